"""The emulators' clocks: holding and advancing by hand, on every kind of clock.

Wall-clock readings are never compared with an upper bound here: a held clock must not
move however long the machine takes, and a released one must not jump.
"""

from __future__ import annotations

import threading
import time

import pytest

from hw_mocks.clock import ManualClock, ScaledClock, SteppingClock
from hw_mocks.motion import StageMechanics

CLOCKS = {
    "scaled": lambda: ScaledClock(1000.0),
    "stepping": lambda: SteppingClock(0.5),
    "manual": lambda: ManualClock(3.0),
}


@pytest.fixture(params=sorted(CLOCKS))
def clock(request):
    return CLOCKS[request.param]()


def test_a_held_clock_stands_still_and_moves_only_by_advance(clock):
    with clock.held() as held:
        assert held is clock and clock.is_held
        t = clock.now()
        time.sleep(0.01)  # 10 emulated seconds of a running ScaledClock(1000)
        assert clock.now() == t and clock.now() == t  # neither time nor readings move it
        assert clock.advance(2.5) == t + 2.5
        assert clock.now() == t + 2.5
    assert not clock.is_held


def test_release_runs_on_from_the_held_reading_without_a_jump():
    clock = ScaledClock(1000.0)
    with clock.held():
        t = clock.now()
        time.sleep(0.02)  # 20 emulated seconds pass outside, none inside
    after = clock.now()
    assert after >= t
    # Without the hold it would read at least 20 s on; the difference is what ran since the
    # release. That is bounded below only: the machine may have paused us, never the clock.
    with clock.held():
        assert clock.now() >= after


def test_holds_nest_and_time_runs_after_the_outermost():
    clock = SteppingClock(1.0)
    with clock.held():
        t = clock.now()
        with clock.held():
            assert clock.now() == t
        assert clock.is_held and clock.now() == t
    assert clock.now() == t + 1.0  # stepping again


def test_advance_while_running_jumps_forward(clock):
    before = clock.now()
    assert clock.advance(100.0) >= before + 100.0
    with pytest.raises(ValueError, match="backwards"):
        clock.advance(-1.0)


def test_the_hold_is_seen_by_other_threads():
    clock = ScaledClock(1000.0)
    readings: list[float] = []
    with clock.held():
        t = clock.now()
        worker = threading.Thread(target=lambda: readings.extend(clock.now() for _ in range(50)))
        worker.start()
        worker.join(60)
    assert readings == [t] * 50


def test_a_stage_move_is_frozen_mid_way_while_the_clock_is_held():
    clock = ScaledClock(1000.0)
    stage = StageMechanics(clock, velocity=1.0, acceleration=100.0)
    with clock.held():
        duration = stage.move_to(10.0)  # 10 emulated seconds
        time.sleep(0.02)
        assert stage.is_moving() and stage.position() == 0.0
        clock.advance(duration / 2)
        assert stage.is_moving() and 0.0 < stage.position() < 10.0
    clock.advance(duration)
    assert not stage.is_moving() and stage.position() == pytest.approx(10.0)


def test_an_instant_gives_one_reading_to_its_thread_only(clock):
    """An emulator's command reads the clock once (:meth:`instant`); other threads, and the
    same thread after the block, see the clock as usual."""
    seen: list[float] = []
    with clock.instant() as t:
        assert clock.now() == t and clock.now() == t  # not even a stepping clock steps
        time.sleep(0.01)  # 10 emulated seconds of a running ScaledClock(1000)
        assert clock.now() == t
        other = threading.Thread(target=lambda: seen.append(clock.now()))
        other.start()
        other.join(10.0)
        with clock.instant() as inner:  # nested: the outer reading holds
            assert inner == t
        moved = clock.advance(2.0)  # by hand: the block follows the clock's new reading
        assert moved >= t + 2.0 and clock.now() == moved
    if isinstance(clock, ManualClock):
        assert seen == [t] and clock.now() == t + 2.0
    else:
        assert seen[0] > t  # the other thread saw the clock run
        assert clock.now() > moved


def test_instant_of_a_clock_without_one_is_a_no_op():
    from hw_mocks.clock import instant

    class Bare:
        def now(self) -> float:
            return 1.0

    with instant(Bare()):
        pass
    with instant(ManualClock(4.0)) as t:
        assert t == 4.0
