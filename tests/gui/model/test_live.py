"""A run's live values (Qt-free): every point kept, light-field rows, bounded arrays."""

from __future__ import annotations

import numpy as np
import pytest

from gui.model.live import LiveData, plot_kind, signed_theta_r
from instrument.run.events import PointCompleted, Progress
from instrument.run.storage import FrameData


def _point(i, angles=(20.0, 0.0, 30.0, 180.0), z=None, status="ok", signal=1.0):
    pos = {"sample_theta": 20.0} if z is None else {"camera_z": z}
    return PointCompleted(i, "sample", status, pos, angles, 1000.0, 1e-3, signal, 0)


def test_points_are_kept_in_preallocated_arrays_and_never_beyond_the_plan():
    live = LiveData("brdf_in_plane", 3)
    for k in range(5):  # two more than planned (a resumed point again): ignored
        live.on_event(_point(k, signal=float(k)))
    live.on_event(Progress(3, 3, 1.5, 0.0))
    snap = live.snapshot()
    assert snap.n_received == 3 and snap.n_done == 3
    assert snap.signal.tolist() == [0.0, 1.0, 2.0] and snap.ok.all()
    assert snap.positions == {"sample_theta": 20.0}
    assert snap.version == 4


def test_signed_theta_r_and_plot_kinds():
    tr = signed_theta_r(np.array([30.0, 30.0]), np.array([0.0, 0.0]), np.array([180.0, 0.0]))
    assert tr.tolist() == [30.0, -30.0]
    assert plot_kind("brdf_hemisphere") == "hemisphere" and plot_kind("dark") == "series"
    assert plot_kind("signature") == "in_plane" and plot_kind("sphere_capture") == "image"


def test_the_light_field_grows_row_by_row_and_skips_dark_frames():
    live = LiveData("lightfield", 4)
    dark = FrameData(np.zeros((8, 16), np.uint16), 1000.0, False, 0.0, 0.0)
    live.on_frame(0, dark)
    live.on_event(_point(0, angles=None))
    for k in (1, 2):
        row = np.tile(np.arange(16, dtype=np.uint16) * k, (8, 1))
        live.on_frame(k, FrameData(row, 500.0, True, 0.0, 0.0))
        live.on_event(_point(k, angles=None, z=float(10 * k)))
    snap = live.snapshot()
    assert snap.field.shape == (4, 16)
    assert np.isnan(snap.field[0]).all() and np.isnan(snap.field[3]).all()
    assert snap.field[2] == pytest.approx(np.arange(16) * 2 / 500.0)
    assert snap.field_y[1:3].tolist() == [10.0, 20.0]
    assert snap.image.shape == (8, 16)
