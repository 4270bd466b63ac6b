"""The orbit track's next chunk built ahead, in pieces, in a paced run's slack (issue 26 item 6): the same bits as a
chunk computed whole, whatever the pieces, and an error while working ahead comes from the read that needs it."""

import pytest

from sim import truth as truth_mod
from stand import scenario
from stand.compose import build
from stand.loop import Stopped
from stand.scenario import DEFAULT_SCENARIO


def tracks(n):
    """``n`` orbit tracks of the default scenario (J2 orbit, the field in it), each read at its start."""
    sc = scenario.load(DEFAULT_SCENARIO)
    out = []
    for _ in range(n):
        with build(sc) as scene:
            out.append(scene.truth.track)
    for t in out:
        t.position(0)
    return out


@pytest.mark.parametrize("piece", [1, 37, 512, 10_000])
def test_a_chunk_built_ahead_in_pieces_has_the_bits_of_one_computed_whole(piece):
    whole, ahead = tracks(2)
    assert whole.field_N is not None  # the field is interpolated on the same grid: it is checked too
    per_chunk = truth_mod.chunk_points(whole.half_step_ns / 1e9)
    done = []
    while (n := ahead.work_ahead(piece)) > 0:
        done.append(n)
    assert sum(done) == per_chunk + 1 and max(done) <= piece
    assert ahead.work_ahead(piece) == 0  # complete: nothing more until it is used
    for idx in range(per_chunk - 3, 2 * per_chunk + 1):  # the end of the first chunk, then all of the second
        assert ahead.position(idx) == whole.position(idx)
        assert ahead.velocity(idx) == whole.velocity(idx)
        assert ahead.field(idx) == whole.field(idx)
    assert ahead._chunk_start_idx == per_chunk and ahead._ahead is None  # the one built ahead was used
    assert ahead.evaluations == whole.evaluations


def test_nothing_is_built_ahead_before_the_first_read():
    sc = scenario.load(DEFAULT_SCENARIO)
    with build(sc) as scene:
        assert scene.truth.track.work_ahead(100) == 0 and scene.truth.track.evaluations == 0


def test_an_error_while_working_ahead_is_raised_by_the_read_that_needs_the_chunk(monkeypatch):
    (track,) = tracks(1)
    per_chunk = truth_mod.chunk_points(track.half_step_ns / 1e9)

    def broken(t_end):
        raise RuntimeError("orbit propagation failed")

    monkeypatch.setattr(track, "_propagate", broken)
    assert track.work_ahead(100) == 0 and track.work_ahead(100) == 0  # given up after the first failure
    assert track.position(per_chunk - 1) is not None  # the current chunk is untouched
    with pytest.raises(RuntimeError, match="orbit propagation failed"):
        track.position(per_chunk + 1)


@pytest.mark.parametrize("stop", [KeyboardInterrupt, Stopped])
def test_the_operators_stop_while_working_ahead_is_not_taken_for_a_failure(monkeypatch, stop):
    # The stop's signal handler raises in whatever the main thread runs, often this work in a paced run's slack.
    (track,) = tracks(1)

    def interrupted(t_end):
        raise stop("SIGTERM")

    monkeypatch.setattr(track, "_propagate", interrupted)
    with pytest.raises(stop):
        track.work_ahead(100)
    assert not track._ahead_failed
