"""Per-wavelength reduction and fit of lock-in readings (closed loop at the analysis level).

Synthetic 3-filter data: the simulated spectral sample's ground truth (hw_mocks, written
independently of the fitted model) gives the BRDF at each filter's band, the simulated
chopped photodiode's documented model (hw_mocks/sim/photodiode.py) the lock-in R, plus
seeded noise. The pipeline, called on a RunData with the per-point wavelength and lock-in
columns of the run-file contract, must recover n(λ) and ρ(λ) within 2σ, by both routes.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis.brdf.reduction import solid_angle_sr
from hw_mocks.sim.photodiode import ChoppedPhotodiode
from hw_mocks.sim.spectral_sample import SpectralSample
from instrument.pipelines.brdf.spectral import (
    SpectralOptions,
    analyse_spectral,
    detector_of,
    has_wavelength_axis,
    wavelength_groups,
    write_spectral_report,
    write_spectral_results,
)
from instrument.run.runfile import RunData

SAMPLE = {"albedo": [0.25, 0.45, 0.6], "albedo_nm": [450.0, 550.0, 650.0],
          "cauchy_a": 1.62, "cauchy_b_um2": 0.012, "alpha": 0.12}
FILTERS = {1: (450.0, 10.0), 2: (550.0, 10.0), 3: (650.0, 10.0)}
DIODE = {"responsivity_nm": [400.0, 700.0], "responsivity_a_per_w": [0.2, 0.45],
         "u_responsivity_rel": 0.02, "transimpedance_v_per_a": 1e7, "distance_mm": 300.0,
         "aperture_diameter_mm": 5.0, "chopper_hz": 137.0}
P_SOURCE = 2e-3


@dataclasses.dataclass(frozen=True)
class _SpectralRun(RunData):
    """RunData with the columns the run-file contract adds (wavelength, lock-in)."""

    wavelength_nm: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    bandwidth_nm: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    filter_position: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    lockin_r_v: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    lockin_u_r_v: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    lockin_sensitivity_v: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    lockin_overload: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))


def _interp_response(lam: float) -> float:
    return float(np.interp(lam, DIODE["responsivity_nm"], DIODE["responsivity_a_per_w"]))


def _profile_text() -> str:
    lines = ["[photodiode]"]
    for k, v in DIODE.items():
        lines.append(f"{k} = {v}")
    lines += ["[simulation.source]", f"power_w = {P_SOURCE}", "wavelength_nm = 550.0",
              "bandwidth_nm = 400.0", "beam_radius_mm = 1.0",
              "[simulation.filter_wheel.filters]"]
    for pos, (c, bw) in FILTERS.items():
        lines.append(f'"{pos}" = {{center_nm = {c}, bandwidth_nm = {bw}}}')
    return "\n".join(lines) + "\n"


def synthetic_run(seed: int, *, rel_noise: float = 0.01, direct_beam: bool = False
                  ) -> _SpectralRun:
    sample = SpectralSample.from_config(SAMPLE)
    omega, _ = solid_angle_sr(DIODE["aperture_diameter_mm"], DIODE["distance_mm"])
    rng = np.random.default_rng(seed)
    rows = []
    for pos, (lam, bw) in FILTERS.items():
        # light at the sample: the 400 nm wide source through the 10 nm filter
        p_i = P_SOURCE * bw / 400.0
        diode = ChoppedPhotodiode(responsivity_a_per_w=_interp_response(lam),
                                  transimpedance_v_per_a=DIODE["transimpedance_v_per_a"])
        brdf = sample.at_light(lam, bw)
        for ti in (15.0, 35.0, 55.0):
            for tr in np.arange(2.0, 82.0, 2.0):
                f = float(brdf(math.radians(ti), 0.0, math.radians(tr), math.pi))
                p_s = f * p_i * omega * math.cos(math.radians(tr))
                r = diode.signal(p_s, 0.0, chopper_hz=137.0).ac_rms_v
                u = rel_noise * r
                sens = next(s for s in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
                            if r <= 0.8 * s)
                rows.append(("sample", ti, 0.0, tr, 180.0, lam, bw, pos,
                             r + u * rng.standard_normal(), u, sens))
        if direct_beam:
            r = diode.signal(p_i, 0.0, chopper_hz=137.0).ac_rms_v
            rows.append(("direct_beam", math.nan, 0.0, math.nan, 0.0, lam, bw, pos,
                         r * (1 + 1e-3 * rng.standard_normal()), 1e-3 * r, 1.0))
    cols = list(zip(*rows, strict=True))
    n = len(rows)

    def arr(k: int) -> np.ndarray:
        return np.array(cols[k], dtype=float)

    zeros = np.zeros(n)
    return _SpectralRun(
        path=Path("synthetic.h5"), run_id="synthetic", plan_kind="brdf_in_plane",
        plan_name="spectral", sample_name="glass", status="complete",
        index=np.arange(n), label=np.array(cols[0]), point_status=np.zeros(n, dtype=int),
        theta_i=arr(1), phi_i=arr(2), theta_r=arr(3), phi_r=arr(4), exposure_us=zeros,
        power_w=zeros, signal=zeros, n_frames=np.zeros(n, dtype=int),
        frame_start=np.zeros(n, dtype=int), positions=np.zeros((n, 0)), axes=(),
        frame_point=np.zeros(0, dtype=int), frame_exposure_us=np.zeros(0),
        frame_light=np.zeros(0, dtype=bool), acquisition={}, geometry={},
        profile_text=_profile_text(),
        plan_text='[acquisition]\ndetectors = ["lockin"]\n', calibration={},
        wavelength_nm=arr(5), bandwidth_nm=arr(6), filter_position=arr(7).astype(int),
        lockin_r_v=arr(8), lockin_u_r_v=arr(9), lockin_sensitivity_v=arr(10),
        lockin_overload=np.zeros(n, dtype=int))


def _check_recovered(fit) -> None:
    sample = SpectralSample.from_config(SAMPLE)
    assert fit.detector == "lockin"
    np.testing.assert_allclose(fit.wavelength_nm, [450.0, 550.0, 650.0])
    for name in ("rho", "n", "alpha"):
        val, err = fit.parameter(name)
        truth = np.array([sample.truth(lam)[name] for lam in fit.wavelength_nm])
        assert np.all(np.isfinite(err)) and np.all(err > 0), name
        assert np.all(np.abs(val - truth) < 2.0 * err), (name, val, truth, err)


def test_run_columns_group_by_filter_and_name_the_detector() -> None:
    run = synthetic_run(0, direct_beam=True)
    assert has_wavelength_axis(run)
    groups = wavelength_groups(run)
    assert [g.filter_position for g in groups] == [1, 2, 3]
    assert [g.rows.size for g in groups] == [120, 120, 120]  # direct beam not scattering
    assert detector_of(run) == "lockin"


def test_absolute_route_recovers_n_and_rho_per_wavelength() -> None:
    fit = analyse_spectral(synthetic_run(1), SpectralOptions(u_incident_power_rel=0.0))
    _check_recovered(fit)


def test_ratio_route_recovers_them_and_agrees_with_the_absolute_route() -> None:
    run = synthetic_run(2, direct_beam=True)
    ratio = analyse_spectral(run, SpectralOptions(route="ratio"))
    _check_recovered(ratio)
    absolute = analyse_spectral(run, SpectralOptions(u_incident_power_rel=0.0))
    for name in ("rho", "n"):
        a, ua = absolute.parameter(name)
        r, ur = ratio.parameter(name)
        assert np.all(np.abs(a - r) < 2 * np.hypot(ua, ur)), name


def test_ratio_route_without_a_direct_beam_says_what_to_give() -> None:
    with pytest.raises(ValueError, match="direct_beam"):
        analyse_spectral(synthetic_run(3), SpectralOptions(route="ratio"))


def test_run_without_wavelength_axis_is_one_lock_in_group_or_refused() -> None:
    """Without a wavelength per point the lock-in's readings are one group at the light's
    wavelength (the simulated source's 550 nm here); the camera's are refused (scatterlab
    fit reduces them)."""
    base = synthetic_run(4)
    run = dataclasses.replace(base, wavelength_nm=np.full(base.n_points, np.nan),
                              filter_position=np.full(base.n_points, -1))
    sample = SpectralSample.from_config(SAMPLE)
    keep = np.flatnonzero(base.filter_position == 2)  # the 550 nm filter's points
    one = dataclasses.replace(
        run, **{k: getattr(run, k)[keep] for k in (
            "index", "label", "point_status", "theta_i", "phi_i", "theta_r", "phi_r",
            "exposure_us", "power_w", "signal", "n_frames", "frame_start", "wavelength_nm",
            "bandwidth_nm", "filter_position", "lockin_r_v", "lockin_u_r_v",
            "lockin_sensitivity_v", "lockin_overload")},
        positions=run.positions[keep])
    # the whole source band at the sample: 400 nm wide, so the power is the source's
    fit = analyse_spectral(one, SpectralOptions(models=("lambert+ggx_fresnel",),
                                                incident_power_w={-1: P_SOURCE * 10 / 400}))
    (wf,) = fit.fits
    assert wf.group.wavelength_nm == 550.0 and wf.group.rows.size == keep.size
    rho, err = fit.parameter("rho")
    assert abs(rho[0] - sample.truth(550.0)["rho"]) < 3 * err[0]
    with pytest.raises(ValueError, match="no wavelength axis"):
        analyse_spectral(run, SpectralOptions(detector="camera"))


# slow: 6.7 s CPU, 5.7 s of it the three per-wavelength reports' figures; the cheaper
# test_fit_report.py::test_cli_fit_writes_analysis_and_report checks the same report writer
# (write_report, one per wavelength here) in the default run, and test_results below this
# one's results file
@pytest.mark.slow
def test_report(tmp_path: Path) -> None:
    fit = analyse_spectral(synthetic_run(5), SpectralOptions(u_incident_power_rel=0.01))
    page = write_spectral_report(tmp_path, fit)
    assert page.is_file() and (tmp_path / "spectral.png").is_file()
    assert (tmp_path / "550nm" / "index.html").is_file()


def test_results(tmp_path: Path) -> None:
    fit = analyse_spectral(synthetic_run(5), SpectralOptions(u_incident_power_rel=0.01))
    run_file = tmp_path / "run.h5"
    saved = write_spectral_results(run_file, fit, options=SpectralOptions(), folder=tmp_path)
    with h5py.File(saved, "r") as f:
        s = f["entry/analysis/spectral"]
        np.testing.assert_allclose(s["wavelength_nm"][()], [450.0, 550.0, 650.0])
        names = [x.decode() if isinstance(x, bytes) else x for x in s["param_names"][()]]
        assert names == ["rho", "n", "alpha"]
        assert s["params"].shape == (3, 3) and np.all(s["stderr"][()] > 0)
        assert "wl_550nm/chosen/params" in f["entry/analysis"]
