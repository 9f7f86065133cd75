"""The one run-file reader: what the writer stored comes back, and a broken file is named."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from instrument.run.runfile import (
    RunFileError,
    read_plan_kind,
    read_planned,
    read_run,
    read_summary,
)
from instrument.run.storage import RunStore
from tests.instrument.run.test_storage import header, rec


@pytest.fixture
def run_file(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(4), fsync=False)
    for i in range(3):
        store.append(rec(i, frames=2))
    store.close("finished")
    return path


def test_points_and_frames_read_back_as_written(run_file):
    run = read_run(run_file)
    assert run.run_id == "r1" and run.plan_kind == "brdf_in_plane" and run.status == "finished"
    assert run.sample_name == "s" and run.axes == ("sample_theta", "detector_theta")
    np.testing.assert_array_equal(run.index, [0, 1, 2])
    np.testing.assert_allclose(run.position("detector_theta"), [0.0, 2.0, 4.0])
    assert np.all(np.isnan(run.position("camera_z")))
    assert run.frame_shape == (16, 24) and run.frame_saturated.shape == (6,)
    light, exposures, darks = run.frames_of(1)
    expected = rec(1, frames=2).frames
    np.testing.assert_array_equal(light, [f.data for f in expected])
    np.testing.assert_allclose(exposures, [100.0, 200.0])
    assert darks is None  # no dark frames at those exposures in this run
    assert run.calibration == {"dark": "run-0"}
    assert run.identities["sample_theta"]["serial"] == "1"


def test_planned_points_and_summary(run_file):
    planned = read_planned(run_file)
    assert planned.label == ("sample",) * 4 and planned.axes == ("sample_theta",
                                                                 "detector_theta")
    np.testing.assert_allclose(planned.targets[:, 1], [0.0, 2.0, 4.0, 6.0])
    assert all(math.isnan(x) for x in planned.exposure_us)
    s = read_summary(run_file)
    assert (s.n_points, s.n_planned, s.n_frames, s.frame_shape) == (3, 4, 6, (16, 24))
    assert s.sample_name == "s" and s.axes == ("sample_theta", "detector_theta")
    assert read_plan_kind(run_file) == "brdf_in_plane"


def test_a_file_without_the_layout_is_named_not_a_keyerror(tmp_path, run_file):
    bare = tmp_path / "bare.h5"
    with h5py.File(bare, "w") as f:
        f.create_group("entry").attrs["plan_kind"] = "lightfield"
    assert read_plan_kind(bare) == "lightfield"
    with pytest.raises(RunFileError, match="not a complete scatterlab run file"):
        read_run(bare)
    empty = tmp_path / "empty.h5"
    h5py.File(empty, "w").close()
    with pytest.raises(RunFileError, match="not a scatterlab run file"):
        read_plan_kind(empty)
