"""Fuzz the display node's receive path: random bytes and valid-CRC state messages with extreme
fields. Nothing may raise, every datagram is accounted for, and whatever is rendered stays within
the renderer's smear cap (the bound on a frame's work; time itself is measured by `stand bench`).

Deterministic: ``derandomize=True`` fixes the examples, so a run here is a run in CI.
"""

from __future__ import annotations

import math
import random
import struct
import zlib

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sim.time import Epoch
from stand.display import DisplayNode, StateSender
from star_screen.catalog import Catalog
from star_screen.geometry import default_bench
from star_screen.outputs import FrameQueue
from star_screen.render import Renderer
from star_screen.state_message import (
    MAX_RATE_RAD_S,
    MAX_SPEED_M_S,
    DisplayState,
    StateMessageError,
    decode,
    encode,
)

from .deadline import deadline

EPOCH = Epoch.from_iso("2026-01-01T00:00:00Z")
SENDER = ("127.0.0.1", 40000)
FUZZ = settings(derandomize=True, deadline=None, max_examples=150,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_NODE: list[DisplayNode] = []
_RENDERER: list[Renderer] = []


def renderer() -> Renderer:
    if not _RENDERER:  # the catalog costs a second to load: once per module
        _RENDERER.append(Renderer(default_bench(320, 180), Catalog.load(mag_limit=8.0)))
    return _RENDERER[0]


def node() -> DisplayNode:
    """One node for every example, torn down at the end of the module."""
    if not _NODE:
        _NODE.append(DisplayNode(("127.0.0.1", 0), renderer(), FrameQueue(2), detector=True, allow=None,
                                 stream_hold_s=0.0))
    return _NODE[0]


def teardown_module(module):
    while _NODE:
        _NODE.pop().close()


extreme = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e300, -1e300, 5e-324, 299_792_458.0, 2.0e8, MAX_SPEED_M_S, 2 * math.pi, 7.0]),
    st.floats(-10.0, 10.0),
)
plausible_q = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: math.hypot(*q) > 0.1).map(
    lambda q: tuple(x / math.hypot(*q) for x in q))
unit3 = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda u: math.hypot(*u) > 0.1).map(
    lambda u: tuple(x / math.hypot(*u) for x in u))
ext3 = st.tuples(extreme, extreme, extreme)
#: Each field: (plausible values, extreme values). Rates reach past the renderer's smear cap.
FIELDS = {
    "epoch": (st.tuples(st.just(EPOCH.tai1), st.floats(-1.0, 1.0), st.integers(-(10**16), 10**16),
                        st.floats(-0.9, 0.9)),
              st.tuples(extreme, extreme, st.integers(-(2**63), 2**63 - 1), extreme)),
    "q_SN": (plausible_q, st.tuples(extreme, extreme, extreme, extreme)),
    "v": (st.tuples(*[st.floats(-8000, 8000)] * 3), ext3),
    "omega": (st.tuples(*[st.floats(-0.3, 0.3)] * 3), ext3),
    "sun": (unit3, ext3),
    "moon": (unit3, ext3),
}


@st.composite
def state_message(draw) -> bytes:
    """A state message whose CRC is right, with any flags; none, one or several of its fields get
    extreme numbers (NaN, infinities, 1e300, c, subnormals), the rest plausible ones."""
    flags = draw(st.integers(0, 15))
    wild = draw(st.one_of(st.just(set()), st.sets(st.sampled_from(sorted(FIELDS)), min_size=1, max_size=3)))
    val = {name: draw(pair[name in wild]) for name, pair in FIELDS.items()}
    tai1, tai2, off_ns, dut1 = val["epoch"]
    body = struct.pack("<4sHHIQq ddqd 4d 3d", b"SSST", 1, flags, draw(st.integers(0, 2**32 - 1)),
                       draw(st.integers(0, 2**64 - 1)), draw(st.integers(-(2**63), 2**63 - 1)), tai1, tai2,
                       off_ns, dut1, *val["q_SN"], *val["v"])
    for bit, name in enumerate(("omega", "sun", "moon")):
        if flags & (1 << bit):
            body += struct.pack("<3d", *val[name])
    data = body + struct.pack("<I", zlib.crc32(body))
    if flags & 8:
        data += draw(st.binary(min_size=32, max_size=32))
    return data


#: Garbage, and messages with one byte cut out.
broken = st.one_of(st.binary(max_size=300),
                   state_message().flatmap(lambda d: st.integers(0, len(d)).map(lambda i: d[:i] + d[i + 1:])))


def _outcomes(stats) -> int:
    return (stats.corrupt + stats.duplicate + stats.out_of_order + stats.errors.get("sender", 0)
            + stats.errors.get("stream", 0))


@FUZZ
@given(data=state_message())
def test_receive_path_never_raises_and_accounts_for_every_message(data):
    _receive_one(data)


@FUZZ
@given(data=broken)
def test_receive_path_refuses_garbage_and_cut_messages(data):
    assert _receive_one(data) is None


def _receive_one(data: bytes):
    """One datagram through the node's receive path, checked; returns the frame rendered or None."""
    n = node()
    st_ = n.stats
    before = (st_.received, _outcomes(st_), dict(st_.errors), st_.rendered)
    with deadline(30.0, "receiving one datagram"):
        state = n._accept(data, None, SENDER)
        frame = None if state is None else n._render_safely(state)
    assert st_.received == before[0] + 1
    if state is None:  # refused or dropped, and counted as exactly one outcome
        assert _outcomes(st_) == before[1] + 1
        return None
    # Accepted: it passed every physical check, so it is drawable ...
    assert abs(math.hypot(*state.v_sc_gcrs_m_s)) < MAX_SPEED_M_S
    assert state.omega_SN_S is None or math.hypot(*state.omega_SN_S) <= MAX_RATE_RAD_S
    assert 1900 <= state.epoch.decimal_year <= 2101
    if frame is None:  # ... or its smear is longer than the renderer draws, and that is counted
        grown = {k: v - before[2].get(k, 0) for k, v in st_.errors.items() if v != before[2].get(k, 0)}
        assert grown == {"smear": 1}, (grown, st_.last_error)
        return None
    # Rendered: tagged with its sim time, and the smear, the only unbounded work, was capped.
    assert frame.time_tag_ns == state.sim_time_ns
    assert 1 <= frame.smear_samples <= n.renderer.max_smear_samples
    assert frame.screen is not None and frame.detector is not None and math.isfinite(float(frame.detector.sum()))
    return frame


@FUZZ
@given(data=state_message())
def test_decode_refuses_only_with_a_named_field(data):
    try:
        decode(data)
    except StateMessageError as exc:
        assert exc.field and exc.field.split("_")[0] in str(exc) or exc.field in ("crc32", "length", "flags")


@settings(derandomize=True, deadline=None, max_examples=20)
@given(seed=st.integers(0, 2**32 - 1))
def test_valid_states_round_trip_through_the_checks(seed):
    rnd = random.Random(seed)
    q = [rnd.gauss(0, 1) for _ in range(4)]
    q = tuple(x / math.hypot(*q) for x in q)
    s = DisplayState(rnd.randrange(2**63), rnd.randrange(2**40), EPOCH.add_ns(rnd.randrange(10**15)), q,
                     tuple(rnd.uniform(-8000, 8000) for _ in range(3)),
                     tuple(rnd.uniform(-0.1, 0.1) for _ in range(3)), stream_id=rnd.randrange(2**32))
    assert decode(encode(s)) == s


def test_a_flood_of_fuzzed_datagrams_over_udp_leaves_the_node_serving():
    """300 seeded datagrams (garbage, extreme fields, a few good states) through the real socket, in
    rounds of 100 (the kernel's default receive buffer holds about 240 small datagrams)."""
    rnd = random.Random(11)
    good = []
    with DisplayNode(("127.0.0.1", 0), renderer(), FrameQueue(2)) as n, \
            StateSender(*n.address, scenario_epoch=EPOCH, stream_id=77) as s:
        for r in range(3):
            for i in range(100 * r, 100 * (r + 1)):
                kind = rnd.random()
                if kind < 0.4:
                    s.send_bytes(rnd.randbytes(rnd.randrange(0, 300)))
                elif kind < 0.9:
                    body = bytearray(encode(DisplayState(i, i, EPOCH, (1.0, 0.0, 0.0, 0.0), stream_id=77)))
                    off = rnd.randrange(20, len(body) - 4)
                    value = struct.pack("<d", rnd.choice([math.inf, math.nan, 1e300, -1e300, 3e8]))
                    body[off: off + 8] = value[: len(body) - 4 - off]
                    body[-4:] = struct.pack("<I", zlib.crc32(bytes(body[:-4])))
                    s.send_bytes(bytes(body))
                else:
                    good.append(i)
                    s.send_state(DisplayState(i, i, EPOCH, (1.0, 0.0, 0.0, 0.0), stream_id=77))
            with deadline(60.0, "serving the flood"):
                stats = n.serve(timeout_s=0.3)
            assert stats.stop_reason == "timeout" and stats.received == 100 * (r + 1)
    assert stats.rendered >= 3 and n.log[-1].sequence == good[-1]  # the newest good state is on screen
    assert stats.corrupt + stats.superseded + stats.out_of_order + stats.duplicate + stats.rendered == 300


@FUZZ
@given(omega=st.one_of(st.none(), st.tuples(*[st.floats(-0.3, 0.3)] * 3), ext3), v=st.one_of(st.none(), ext3),
       exposure=st.one_of(st.none(), st.floats(0.0, 1.0), extreme))
def test_renderer_refuses_what_it_cannot_draw_and_caps_the_smear(omega, v, exposure):
    r = renderer()
    try:
        frame = r.render((1.0, 0.0, 0.0, 0.0), EPOCH, v_sc_gcrs_m_s=v, omega_SN_S=omega, exposure_s=exposure)
    except ValueError as exc:  # SmearTooLong is one; each names the argument it refused
        assert any(name in str(exc) for name in ("omega_SN_S", "v_sc_gcrs_m_s", "exposure_s")), str(exc)
        return
    assert 1 <= frame.smear_samples <= r.max_smear_samples
    assert math.isfinite(float(frame.detector.sum()))
