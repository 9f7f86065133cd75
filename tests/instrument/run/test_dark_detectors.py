"""Per-point darks are read only by the detectors that need them: a camera plan that leaves
``detectors`` at its default reads the power meter beside the camera, but not its dark;
naming the detectors (or ``dark_detectors``) darks each one listed. Counted in the run file
through the engine on the emulated bench."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.cli import main
from instrument.plans import parse_plan
from instrument.plans.planfile import PlanError
from instrument.run.runfile import read_run

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "darks per detector"
[sample]
name = "s"
[scan]
skip_beam_points = true
theta_i = [30]
theta_r = [-40, 10]
[acquisition]
exposure_us = 2000
dark = "per_point"
{detectors}
"""


def _dark_counts(tmp_path, detectors: str) -> tuple[int, int, int]:
    """(points, camera dark frames, power-meter dark readings) of a run of PLAN."""
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.format(detectors=detectors), encoding="utf-8")
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--bench", "sim", "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    run = read_run(path)
    rows = run.brdf_rows()
    assert np.all(np.isfinite(run.power_w[rows]))  # the meter is read at every point
    dark_frames = int(np.sum(~run.frame_light.astype(bool)))
    pm_darks = int(np.sum(np.isfinite(run.power_dark_w[rows])))
    return rows.size, dark_frames, pm_darks


def test_default_detectors_take_camera_darks_and_no_power_meter_dark(tmp_path):
    n, camera_darks, pm_darks = _dark_counts(tmp_path, "")
    assert n == 2 and camera_darks == n and pm_darks == 0


def test_named_detectors_each_take_their_dark(tmp_path):
    n, camera_darks, pm_darks = _dark_counts(
        tmp_path, 'detectors = ["camera", "power_meter"]')
    assert n == 2 and camera_darks == n and pm_darks == n


def test_dark_detectors_chooses_among_the_listed_and_keeps_the_camera():
    text = PLAN.format(detectors='detectors = ["camera", "power_meter"]\n'
                       'dark_detectors = ["camera"]')
    pol = parse_plan(text, source="plan").acquisition
    assert pol.reads_dark("camera") and not pol.reads_dark("power_meter")
    assert not pol.reads_dark("lockin")  # not read at all
    for bad in ('["lockin"]', '["power_meter"]'):
        with pytest.raises(PlanError) as err:
            parse_plan(PLAN.format(detectors='detectors = ["camera", "power_meter"]\n'
                                   f"dark_detectors = {bad}"), source="plan")
        assert "acquisition.dark_detectors" in str(err.value)
