"""The angular error model of recorded (read-back) angles: resolution and repeatability
per stage, from the profile or defaults by driver kind; the position tolerance is not an
error of a read-back angle."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis.brdf.reduction import angular_uncertainty
from instrument.bench.angles import angular_model, stage_angle
from instrument.bench.profile import ProfileError, load_profile, parse_profile


def _profile(name: str) -> dict:
    return tomllib.loads(load_profile(name).source_text)


def test_the_sim_bench_angles_are_known_to_the_read_back_quantum():
    m = angular_model(_profile("sim"))
    # K10CR1: 409600 µsteps per 3°, a quantum of 7.3e-6°: σ = q/√12 = 2.1e-6°; the
    # emulated stages' read-back is the world's position (no repeatability error) —
    # not the 0.01° position tolerance / √3 = 0.0058° the reduction used to add
    assert math.degrees(m.sigma_theta_i_rad) == pytest.approx(3 / 409600 / math.sqrt(12))
    assert m.sigma_theta_r_rad == pytest.approx(m.sigma_theta_i_rad)
    assert m.warnings == ()


def test_a_real_stage_without_a_declared_repeatability_is_named():
    real = Path(__file__).parents[3] / "examples" / "bench_inplane_real.toml"
    m = angular_model(tomllib.loads(load_profile(str(real)).source_text))
    assert len(m.warnings) == 2
    assert "devices.sample_theta.repeatability" in m.warnings[0]


def test_profile_keys_set_the_model_and_both_stages_enter_theta_r():
    s = stage_angle("sample_theta", {"driver": "thorlabs_apt", "url": "/dev/ttyUSB0",
                                     "readback_resolution": 0.001, "repeatability": 0.03})
    assert s.sigma == pytest.approx(math.hypot(0.001 / math.sqrt(12), 0.03 / math.sqrt(3)))
    m = angular_model({"devices": {
        "sample_theta": {"url": "/dev/a", "repeatability": 0.03},
        "detector_theta": {"url": "/dev/b", "repeatability": 0.04}}})
    si, sd = 0.03 / math.sqrt(3), 0.04 / math.sqrt(3)
    assert math.degrees(m.sigma_theta_i_rad) == pytest.approx(si)
    assert math.degrees(m.sigma_theta_r_rad) == pytest.approx(math.hypot(si, sd))


@pytest.mark.parametrize(("key", "value"), [("repeatability", -0.1),
                                            ("readback_resolution", 0.0),
                                            ("repeatability", "fine")])
def test_bad_angular_keys_name_their_field(key, value):
    text = load_profile("sim").source_text.replace(
        "position_tolerance = 0.01\n", f"position_tolerance = 0.01\n{key} = {value!r}\n"
        .replace("'", '"'), 1)
    with pytest.raises(ProfileError) as err:
        parse_profile(text, source="test")
    assert err.value.errors[0].path == f"devices.sample_theta.{key}"


def test_the_theta_i_slope_is_not_differenced_across_a_coarse_grid():
    # a lobe that moves with θi: across 20° steps the difference is no local slope
    ti = np.radians(np.repeat([20.0, 40.0, 60.0], 3))
    tr = np.radians(np.tile([10.0, 30.0, 50.0], 3))
    f = 1 + np.exp(-((np.degrees(tr) - np.degrees(ti)) / 5) ** 2)
    u = angular_uncertainty(f, ti, tr, sigma_theta_i=0.01)
    assert np.all(u == 0.0)
    # 2° steps resolve it: a finite slope
    ti2 = np.radians(np.repeat([20.0, 22.0, 24.0], 3))
    f2 = 1 + 0.1 * np.degrees(ti2)
    u2 = angular_uncertainty(f2, ti2, tr, sigma_theta_i=0.01)
    assert u2 == pytest.approx(np.full(9, 0.1 * np.degrees(1) * 0.01), rel=1e-6)


def test_on_a_type_i_bench_each_arc_alone_sets_its_angle():
    """The sample stands still: σθi is the source arc's read-back, σθr the detector
    arc's, nothing shared (ADR 0099)."""
    data = _profile("sim-type-i")
    data["devices"]["source_arc"]["repeatability"] = 0.002
    data["devices"]["detector_arc"]["readback_resolution"] = 0.001
    m = angular_model(data)
    assert [s.role for s in m.stages] == ["source_arc", "detector_arc"]
    assert math.degrees(m.sigma_theta_i_rad) == pytest.approx(
        math.hypot(3 / 409600 / math.sqrt(12), 0.002 / math.sqrt(3)))
    assert math.degrees(m.sigma_theta_r_rad) == pytest.approx(0.001 / math.sqrt(12))
