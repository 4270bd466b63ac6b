"""Display node on loopback: the sim sends state over UDP, the node renders it locally."""

import numpy as np
import pytest

from sim.time import Epoch
from stand.cli import main
from stand.display import DisplayNode, StateSender
from star_screen.attitude import q_SN_from_radec_roll
from star_screen.catalog import Catalog
from star_screen.geometry import default_bench
from star_screen.outputs import FrameQueue
from star_screen.render import Renderer
from star_screen.state_message import DisplayState, encode
from tests.oracles import require

EPOCH = Epoch.from_iso("2026-01-01T00:00:00Z")
W, H = 640, 360


@pytest.fixture(scope="module")
def catalog():
    return Catalog.load()


@pytest.fixture
def node(catalog):
    with DisplayNode(("127.0.0.1", 0), Renderer(default_bench(W, H), catalog), FrameQueue(8), detector=True) as n:
        yield n


@pytest.fixture
def sender(node):
    with StateSender(*node.address, scenario_epoch=EPOCH, stream_id=1) as s:
        yield s


def _q(ra, dec, roll=0.0):
    return q_SN_from_radec_roll(ra, dec, roll)


def test_node_frames_equal_local_frames_bit_for_bit(node, sender, catalog):
    local = Renderer(default_bench(W, H), catalog)
    cases = [
        dict(q=_q(83.8, -5.4, 12.0), t_ns=0, v=(0.0, 0.0, 0.0), omega=None),
        dict(q=_q(0.01, 89.9), t_ns=100_000_000, v=(-6100.0, 3500.0, 1200.0), omega=None),
        dict(q=_q(359.99, -30.0, 200.0), t_ns=250_000_123, v=(7000.0, 0.0, 0.0), omega=(0.0, 0.01, 0.02)),
    ]
    for c in cases:
        sent = sender.send(c["q"], c["t_ns"], v_sc_gcrs_m_s=c["v"], omega_SN_S=c["omega"],
                           sun_N=(1.0, 0.0, 0.0))
        stats = node.serve(max_frames=1, timeout_s=5.0)
        assert stats.stop_reason == "max_frames"
        got = node.output.latest()
        want = local.render(c["q"], EPOCH.add_ns(c["t_ns"]), v_sc_gcrs_m_s=c["v"], omega_SN_S=c["omega"],
                            time_tag_ns=c["t_ns"])
        assert got.time_tag_ns == c["t_ns"] == sent.sim_time_ns
        assert got.screen.max() > 0
        np.testing.assert_array_equal(got.screen, want.screen)
        np.testing.assert_array_equal(got.detector, want.detector)
        np.testing.assert_array_equal(got.stars.hip, want.stars.hip)
        assert got.bodies["sender_u_N"]["sun"] == (1.0, 0.0, 0.0)
    assert [f.sequence for f in node.log] == [0, 1, 2]
    assert [f.sim_time_ns for f in node.log] == [c["t_ns"] for c in cases]
    assert node.stats.rendered == 3 and node.stats.corrupt == 0


def test_corrupt_datagrams_are_counted_and_skipped(node, sender):
    good = sender.send(_q(10, 10), 1_000)
    bad_crc = bytearray(encode(good))
    bad_crc[40] ^= 0xFF
    sender.send_bytes(b"not a state message at all")
    sender.send_bytes(bytes(bad_crc))
    sender.send_bytes(encode(good)[:-3])
    stats = node.serve(max_frames=2, timeout_s=0.3)
    assert (stats.received, stats.corrupt, stats.rendered) == (4, 3, 1)
    assert stats.stop_reason == "timeout" and "length" in stats.last_error
    assert node.output.latest().time_tag_ns == 1_000


def test_late_duplicate_and_out_of_order_states_are_dropped(node, sender):
    def send(seq, t_ns):
        sender.sequence = seq
        sender.send(_q(20, 20), t_ns)

    send(5, 500)
    send(3, 300)  # arrives after 5: older, dropped
    assert node.serve(max_frames=1, timeout_s=2.0).rendered == 1
    assert node.output.latest().time_tag_ns == 500
    send(5, 500)  # duplicate of the frame shown
    send(4, 400)  # late
    send(6, 600)
    send(7, 700)  # 6 and 7 waiting together: only the newest is rendered
    stats = node.serve(max_frames=5, timeout_s=0.3)
    assert (stats.duplicate, stats.out_of_order, stats.superseded, stats.rendered) == (1, 2, 1, 2)
    assert [f.sim_time_ns for f in node.log] == [500, 700]
    assert all(f.time_tag_ns is not None for f in node.output._frames)


def test_a_restarted_sender_starts_a_new_stream_once_the_old_one_is_quiet(node, sender):
    now = [0]
    node.clock = lambda: now[0]
    sender.sequence = 100
    sender.send(_q(30, 0), 1)
    node.serve(max_frames=1, timeout_s=2.0)
    with StateSender(*node.address, scenario_epoch=EPOCH, stream_id=2) as again:
        now[0] += 400_000_000  # 0.4 s after the live stream spoke: another stream may not take over
        again.send(_q(30, 0), 2)
        stats = node.serve(max_frames=1, timeout_s=0.3)
        assert (stats.rendered, stats.stream_restarts, stats.errors) == (1, 0, {"stream": 1})
        now[0] += 200_000_000  # 0.6 s of silence: the restarted sender is adopted, sequence 0 and up
        again.send(_q(30, 0), 3)
    stats = node.serve(max_frames=1, timeout_s=2.0)
    assert (stats.rendered, stats.stream_restarts, stats.out_of_order) == (2, 1, 0)
    assert node.output.latest().time_tag_ns == 3


def test_node_stops_by_itself(node):
    stats = node.serve(timeout_s=0.05)
    assert (stats.stop_reason, stats.rendered) == ("timeout", 0)
    assert node.serve(duration_s=0.05, timeout_s=None).stop_reason == "duration"
    with pytest.raises(ValueError, match="max_frames = 0"):
        node.serve(max_frames=0)


def test_sender_and_node_refuse_bad_arguments(catalog):
    with pytest.raises(ValueError, match="port = 0"):
        StateSender("127.0.0.1", 0)
    with StateSender("127.0.0.1", 9, stream_id=3) as s, pytest.raises(ValueError, match="scenario_epoch"):
        s.send(_q(0, 0), 0)
    with pytest.raises(ValueError, match="renderer and an output"):
        DisplayNode(("127.0.0.1", 0))
    with pytest.raises(ValueError, match="bind = 192.0.2.1"):
        DisplayNode(("192.0.2.1", 0), Renderer(default_bench(W, H), catalog), FrameQueue())


def test_cli_display_node_stops_on_timeout_and_reports(capsys):
    assert main(["display-node", "--bind", "127.0.0.1:0", "--screen", f"{W}x{H}", "--timeout", "0.05"]) == 0
    out = capsys.readouterr()
    assert "listening on 127.0.0.1:" in out.err and "stop_reason timeout" in out.out and "rendered 0" in out.out


@pytest.mark.parametrize(
    "argv, field",
    [
        (["--bind", "localhost"], "--bind 'localhost'"),
        (["--bind", "127.0.0.1:70000"], "--bind"),
        (["--bind", "127.0.0.1:0", "--screen", "big"], "--screen 'big'"),
        (["--bind", "127.0.0.1:0", "--max-frames", "0"], "--max-frames 0"),
        (["--bind", "127.0.0.1:0", "--timeout", "-1"], "--timeout -1"),
    ],
)
def test_cli_display_node_usage_errors(argv, field, capsys):
    assert main(["display-node", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stand: error: ") and field in err and err.count("\n") == 1


def test_cli_display_node_window_on_dummy_video(monkeypatch, capsys):
    require("pygame", "the display extra (pygame-ce)")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    argv = ["display-node", "--bind", "127.0.0.1:0", "--screen", f"{W}x{H}", "--window", "--windowed",
            "--timeout", "0.05"]
    assert main(argv) == 0
    assert "stop_reason timeout" in capsys.readouterr().out


def test_bench_reports_the_display_node_round_trip():
    from stand.benches.render import display_node_rows

    rows = display_node_rows(3)
    assert [r["name"] for r in rows] == ["display node round trip 1920x1080 median",
                                         "display node round trip 1920x1080 p95"]
    assert all(r["unit"] == "ms" and r["value"] > 0 for r in rows) and "8 rendered, 0 dropped" in rows[0]["note"]


def _node(catalog, **kw):
    return DisplayNode(("127.0.0.1", 0), Renderer(default_bench(W, H), catalog), FrameQueue(4), **kw)


def test_senders_off_the_allow_list_are_refused(catalog):
    with _node(catalog, allow=["192.0.2.0/24"]) as n, StateSender(*n.address, scenario_epoch=EPOCH) as s:
        s.send(_q(10, 10), 1)
        stats = n.serve(max_frames=1, timeout_s=0.3)
        assert (stats.rendered, stats.errors) == (0, {"sender": 1}) and "127.0.0.1" in stats.last_error
    with _node(catalog, allow=["any"]) as n, StateSender(*n.address, scenario_epoch=EPOCH) as s:
        s.send(_q(10, 10), 1)
        assert n.serve(max_frames=1, timeout_s=2.0).rendered == 1
    with pytest.raises(ValueError, match="--allow 'lan'"):
        _node(catalog, allow=["lan"])


def test_a_node_with_a_key_renders_only_signed_state(catalog):
    key = b"0123456789abcdef0123"
    with _node(catalog, key=key) as n:
        with StateSender(*n.address, scenario_epoch=EPOCH, stream_id=1) as plain:
            plain.send(_q(10, 10), 1)
        with StateSender(*n.address, scenario_epoch=EPOCH, stream_id=1, key=b"another key of 20 b") as other:
            other.send(_q(10, 10), 2)
        with StateSender(*n.address, scenario_epoch=EPOCH, stream_id=1, key=key) as good:
            good.send(_q(10, 10), 3)
        stats = n.serve(max_frames=1, timeout_s=2.0)
        assert (stats.rendered, stats.errors, stats.corrupt) == (1, {"hmac": 2}, 2)
        assert n.output.latest().time_tag_ns == 3


def test_a_smear_past_the_cap_is_refused_and_the_node_goes_on(catalog):
    with _node(catalog) as n, StateSender(*n.address, scenario_epoch=EPOCH, stream_id=1) as s:
        fast = 2.0 * n.renderer.max_rate_rad_s()  # within the message's limit, past the renderer's
        s.send(_q(10, 10), 1, omega_SN_S=(0.0, fast, 0.0))
        stats = n.serve(max_frames=1, timeout_s=0.3)
        assert (stats.rendered, stats.errors) == (0, {"smear": 1}) and "max_smear_px" in stats.last_error
        s.send(_q(10, 10), 2, omega_SN_S=(0.0, 0.9 * n.renderer.max_rate_rad_s(), 0.0))
        stats = n.serve(max_frames=1, timeout_s=2.0)
        frame = n.output.latest()
        assert stats.rendered == 1 and 2 < frame.smear_samples <= n.renderer.max_smear_samples


def test_any_render_failure_is_counted_not_raised(catalog):
    with _node(catalog) as n, StateSender(*n.address, scenario_epoch=EPOCH, stream_id=1) as s:
        def broken(*a, **k):
            raise RuntimeError("driver lost")

        n.renderer.render = broken
        s.send(_q(10, 10), 1)
        stats = n.serve(max_frames=1, timeout_s=0.3)
        assert (stats.rendered, stats.errors, stats.stop_reason) == (0, {"render": 1}, "timeout")
        assert "RuntimeError: driver lost" in stats.last_error


def test_cli_reads_the_key_from_a_private_file_or_the_environment(tmp_path, monkeypatch, capsys):
    from stand.display import KEY_ENV, load_key

    f = tmp_path / "key"
    f.write_bytes(b"  a shared key of 26 bytes\n")
    f.chmod(0o600)
    assert load_key(f, environ={}) == b"a shared key of 26 bytes"
    assert load_key(None, environ={KEY_ENV: "from the environment 123"}) == b"from the environment 123"
    assert load_key(None, environ={}) is None
    f.chmod(0o644)
    with pytest.raises(ValueError, match="chmod 600"):
        load_key(f, environ={})
    with pytest.raises(ValueError, match="at least 16"):
        load_key(None, environ={KEY_ENV: "short"})
    monkeypatch.setenv(KEY_ENV, "short")
    assert main(["display-node", "--bind", "127.0.0.1:0", "--timeout", "0.05"]) == 2
    assert KEY_ENV in capsys.readouterr().err
    monkeypatch.setenv(KEY_ENV, "long enough shared key")
    argv = ["display-node", "--bind", "127.0.0.1:0", "--screen", f"{W}x{H}", "--timeout", "0.05", "--allow", "any"]
    assert main(argv) == 0
    assert "refused: none" in capsys.readouterr().out


def test_fifty_spoofed_streams_cannot_take_over_a_live_screen(catalog):
    # The case: 50 datagrams, each with its own stream_id, were each rendered.
    with _node(catalog) as n, StateSender(*n.address, scenario_epoch=EPOCH, stream_id=7) as s:
        s.send(_q(10, 10), 1)
        for k in range(50):
            s.send_state(DisplayState(0, 1000 + k, EPOCH, tuple(_q(200, -40)), stream_id=1000 + k))
        stats = n.serve(max_frames=2, timeout_s=0.3)
        assert (stats.rendered, stats.errors) == (1, {"stream": 50})
        assert n.output.latest().time_tag_ns == 1


def test_cli_display_node_refuses_a_bad_allow_entry(capsys):
    assert main(["display-node", "--bind", "127.0.0.1:0", "--allow", "lab-pc"]) == 2
    assert "--allow 'lab-pc' is not an address or network" in capsys.readouterr().err


def test_the_sender_never_stops_the_sim():
    import socket

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nobody listens there: the kernel answers with ICMP port unreachable
    with StateSender("127.0.0.1", port, scenario_epoch=EPOCH, stream_id=5) as s:
        assert s.send(_q(0, 0), 0, omega_SN_S=(0.0, 0.0, 20.0)) is None  # a tumble past one turn a second
        assert s.refused == 1 and "omega_SN_S" in s.last_error and s.sequence == 0
        for k in range(5):
            s.send(_q(0, 0), k)
        assert s.send_errors >= 1 and "failed" in s.last_error and s.sent + s.send_errors == 5
