"""Elapsed time and time left without pauses; log-axis labels with their decade; a resumed
run's live data starts with the points already measured (Qt-free)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from gui.model.live import LiveData, ProgressClock, decade_label, log_ticks
from instrument.run.events import Progress


class Clock:
    """A clock that moves only when told (no wall time in the test)."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_pauses_count_neither_in_elapsed_nor_in_the_time_left():
    clock = Clock()
    pc = ProgressClock(now=clock)
    pc.start(0)
    # 10 points in 20 s of measuring: 2 s a point
    assert pc.times(Progress(10, 50, 20.0, 80.0)) == pytest.approx((20.0, 80.0))
    pc.paused()
    clock.t += 600.0  # a ten-minute pause
    pc.resumed()
    # the engine's elapsed includes the pause (20 + 600 + 2 s for the next point)
    elapsed, left = pc.times(Progress(11, 50, 622.0, 9999.0))
    assert elapsed == pytest.approx(22.0) and left == pytest.approx(39 * 2.0)
    # a pause in progress is left out too
    pc.paused()
    clock.t += 30.0
    assert pc.paused_s() == pytest.approx(630.0)
    assert pc.times(Progress(11, 50, 652.0, 0.0))[0] == pytest.approx(22.0)


def test_a_resumed_run_estimates_from_its_own_points():
    pc = ProgressClock(now=Clock())
    pc.start(28)  # resumed with 28 of 57 done
    assert math.isnan(pc.times(Progress(28, 57, 0.5, 0.0))[1])
    assert pc.times(Progress(30, 57, 6.0, 0.0)) == pytest.approx((6.0, 27 * 3.0))


@pytest.mark.parametrize(("v", "text"), [(-3.0, "10⁻³"), (0.0, "10⁰"), (2.0, "10²"),
                                         (math.log10(2e-3), "2×10⁻³"),
                                         (math.log10(5e4), "5×10⁴")])
def test_log_labels_carry_their_decade(v, text):
    assert decade_label(v) == text


def test_log_ticks_decades_major_the_rest_minor():
    (step, major), (_, minor) = log_ticks(-3.2, -0.5)
    assert step == 1.0 and major == [-3.0, -2.0, -1.0]
    assert len(minor) == 3 + 8 + 8 + 2  # 7…9e-4, 2…9e-3, 2…9e-2, 2…3e-1
    assert all(-3.2 <= m <= -0.5 for m in minor)
    # less than a decade: no decade inside, the minors still there (labelled 2×10⁻³ …)
    (_, major), (_, minor) = log_ticks(math.log10(2e-3), math.log10(9e-3))
    assert major == [] and [decade_label(m) for m in minor][:2] == ["2×10⁻³", "3×10⁻³"]


def test_prefill_puts_the_measured_points_first():
    live = LiveData("brdf_in_plane", 57, n_done=28)
    n = 28
    run = SimpleNamespace(index=np.arange(n), point_status=np.r_[np.zeros(n - 1), 1],
                          theta_i=np.full(n, 20.0), phi_i=np.full(n, 180.0),
                          theta_r=np.linspace(-60, 70, n), phi_r=np.zeros(n),
                          signal=np.linspace(1, 2, n), power_w=np.full(n, np.nan))
    assert live.prefill(run) == 28
    snap = live.snapshot()
    assert snap.n_received == 28 and snap.index.tolist() == list(range(28))
    assert snap.ok.sum() == 27 and snap.signal[3] == pytest.approx(run.signal[3])
    assert snap.theta_r[5] == pytest.approx(run.theta_r[5], abs=1e-4)
