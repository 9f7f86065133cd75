"""Dynamic range of the lock-in detector against the camera on the same simulated sample.

Metric (docs/decisions/0053): at equal time per point T, each detector adapts its setting
per point (the camera its exposure, HDR; the lock-in its sensitivity range), so

* the **largest** BRDF it measures is where its fastest / least sensitive setting
  saturates: the camera's brightest pixel reaching full well at the shortest exposure; the
  lock-in's R reaching 0.8 of its 1 V rms full scale (where the emulator's auto-range
  stops);
* the **smallest** is where the signal-to-noise ratio of one point falls to 3 with the
  whole time T spent integrating: the camera a light and a dark frame of T/2 each, summed
  over the region of interest (the spot's image: shot noise, read and dark noise of every
  pixel in it, twice for the dark frame); the lock-in at the time constant τ = T/10 (the
  reading settles within 10τ at 24 dB/oct), noise = density·√ENBW, ENBW = 5/(64τ) (SR830
  manual Rev. 2.5 p. 3-25), density the emulator's amplifier noise ⊕ the shot noise of the
  photocurrent (hw_mocks/sim/photodiode.py), and, as a second line, ⊕ the Johnson noise
  √(4kT/R_f)·R_f of the transimpedance resistor (not in the emulator; a real TIA has it).

The dynamic range is log10(f_max/f_min) in decades of BRDF. Both detectors sit 300 mm
from the sample; the geometry, the source (1 mW at 550 nm, 2 mm 1/e² radius) and the
sample (the simulated spectral sample: a dark glass, ρ = 10⁻⁵, n from Cauchy, GGX α = 0.01)
are the same. The in-plane scan (θi = 30°, θr every 0.5°) then counts the points each
detector measures (SNR ≥ 3, not saturated) and the decades between the largest and the
smallest of them. Everything is computed from the simulated devices' models (hw_mocks:
sensor parameters, camera optics, the chopped photodiode, the SR830 emulator's noise), not
by running the engine.

The last row of each table is a lock-in whose transimpedance amplifier switches its gain
(10⁴ … 10⁸ V/A, as current amplifiers used with lock-ins do): the simulated bench's
photodiode has one fixed gain, so that row is the model's extrapolation, not the sim bench.

Run: ``python benchmarks/bench_lockin_dynamic_range.py``
"""

from __future__ import annotations

import math

import numpy as np

from hw_mocks.firmware.sr830 import ENBW_TIMES_TAU
from hw_mocks.sim.camera import OpticsParams
from hw_mocks.sim.photodiode import ELEMENTARY_CHARGE_C, SQUARE_FUNDAMENTAL_RMS
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.spectral_sample import SpectralSample

PLANCK = 6.62607015e-34
LIGHT = 299792458.0
BOLTZMANN = 1.380649e-23

LAMBDA_NM = 550.0
P_I = 1e-3
BEAM_W_MM = 2.0
DIST_MM = 300.0
T_POINT_S = 2.0
THETA_I = math.radians(30.0)
SAMPLE = {"albedo": 1e-5, "cauchy_a": 1.5046, "cauchy_b_um2": 0.0042, "alpha": 0.01}

# photodiode (a Si diode at 550 nm behind a 10⁶ V/A transimpedance amplifier)
RESPONSIVITY = 0.33
GAIN = 1e6
APERTURE_MM = 9.5
AMP_NOISE = 10e-9  # the SR830 emulator's default input noise, V/√Hz
FULL_SCALE_V = 1.0
#: Ambient radiance on the detectors (W m⁻² sr⁻¹): a dark room, a dimmed lab, lab light
#: (a white wall under ~300 lx is of order 0.1–1 in the visible).
AMBIENTS = (0.0, 1e-3, 1e-1)


def camera_limits(theta_r: np.ndarray, ambient: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray, dict]:
    """(f_max, f_min) per θr for the simulated camera (module docstring). ``ambient`` is
    a uniform radiance (W m⁻² sr⁻¹) on every pixel: it caps the exposure at 80 % of full
    well (frames are then averaged to fill T/2) and its shot noise stays after the dark
    frame removes its mean."""
    s, lens = SensorParams(), OpticsParams()
    photon = PLANCK * LIGHT / (LAMBDA_NM * 1e-9)
    omega = math.pi * (0.5 * lens.aperture_diameter_mm) ** 2 / DIST_MM**2
    mag = lens.focal_length_mm / (DIST_MM - lens.focal_length_mm)
    a_px = BEAM_W_MM * mag / (s.pixel_pitch_um * 1e-3)  # 1/e² radius of the spot's image
    # the footprint is stretched by 1/cosθi and seen foreshortened by cosθr
    stretch = np.maximum(np.cos(theta_r), 1e-3) / math.cos(THETA_I)
    peak_frac = 2.0 / (math.pi * a_px * a_px * stretch)  # of the power, in the centre pixel
    n_roi = math.pi * (2.0 * a_px) ** 2 * stretch  # pixels within twice the 1/e² radius
    e_per_w_s = s.quantum_efficiency / photon  # electrons per joule
    per_f = P_I * omega * np.cos(theta_r) * e_per_w_s  # e⁻/s per unit BRDF
    t_min = 10e-6  # the simulated camera's shortest exposure
    f_max = s.full_well_e / (per_f * peak_frac * t_min)
    etendue = math.pi * (0.5e-3 * lens.aperture_diameter_mm) ** 2 * (
        s.pixel_pitch_um * 1e-3 / lens.focal_length_mm) ** 2
    amb_rate = ambient * etendue * e_per_w_s  # e⁻/s per pixel
    budget = T_POINT_S / 2.0
    t = budget if amb_rate == 0 else min(budget, 0.8 * s.full_well_e / amb_rate)
    frames = max(1, math.floor(budget / t + 1e-9))
    var_px = frames * (s.read_noise_e**2 + (s.dark_current_e_per_s + amb_rate) * t)
    # SNR 3: S = 3 √(S + 2 N σ²) → S = (9 + √(81 + 36·2Nσ²))/2
    bg = 2.0 * n_roi * var_px
    s_min = 0.5 * (9.0 + np.sqrt(81.0 + 36.0 * bg))
    f_min = s_min / (per_f * t * frames)
    if amb_rate > 0:  # the shortest exposure already carries the ambient light
        f_max = np.maximum(s.full_well_e - amb_rate * t_min, 0.0) / (per_f * peak_frac * t_min)
    return f_max, f_min, {"spot_radius_px": a_px, "roi_px_at_specular": float(n_roi[0])}


def lockin_limits(theta_r: np.ndarray, *, johnson: bool, ambient: float = 0.0,
                  gain_low: float = GAIN, gain_high: float = GAIN
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(f_max, f_min) per θr for the chopped photodiode and the SR830 (module docstring).
    ``ambient`` (W m⁻² sr⁻¹) reaches the diode unchopped, π L A (photodiode.py): no signal
    at the chopper frequency, but the shot noise of its photocurrent."""
    omega = 2 * math.pi * (1 - math.cos(math.atan(0.5 * APERTURE_MM / DIST_MM)))
    p_amb = math.pi * ambient * math.pi * (0.5e-3 * APERTURE_MM) ** 2
    per_f = P_I * omega * np.cos(theta_r)  # W on the diode per unit BRDF
    # the largest value on the lowest transimpedance, the smallest on the highest
    f_max = 0.8 * FULL_SCALE_V / (SQUARE_FUNDAMENTAL_RMS * RESPONSIVITY * gain_low * per_f)
    v_per_w = SQUARE_FUNDAMENTAL_RMS * RESPONSIVITY * gain_high
    tau = T_POINT_S / 10.0
    enbw = ENBW_TIMES_TAU[4] / tau
    density2 = AMP_NOISE**2 + (4 * BOLTZMANN * 295.0 * gain_high if johnson else 0.0)
    # the shot noise of the photocurrent at the floor is far below the amplifier's
    # (I ~ 1e-14 A → 6e-11 V/√Hz): solve with it included all the same
    f_min = np.empty_like(per_f)
    for k, pf in enumerate(per_f):
        f = 1e-12
        for _ in range(50):
            shot2 = (gain_high**2) * 2 * ELEMENTARY_CHARGE_C * RESPONSIVITY * (f * pf / 2.0
                                                                          + p_amb)
            noise = math.sqrt((density2 + shot2) * enbw)
            f = 3.0 * noise / (v_per_w * pf)
        f_min[k] = f
    return f_max, f_min


def scan(f_true: np.ndarray, f_max: np.ndarray, f_min: np.ndarray) -> tuple[int, float]:
    """(points measured, decades between the largest and smallest measured value)."""
    ok = (f_true >= f_min) & (f_true <= f_max)
    if not ok.any():
        return 0, 0.0
    return int(ok.sum()), float(np.log10(f_true[ok].max() / f_true[ok].min()))


def main() -> None:
    sample = SpectralSample.from_config(SAMPLE)
    brdf = sample.at_light(LAMBDA_NM, 10.0)
    theta_r = np.radians(np.arange(-85.0, 85.01, 0.5))
    # signed θr: > 0 on the specular side (φr = π), < 0 on the source side (φr = 0);
    # the detector cannot sit within 3° of the incident beam
    keep = np.abs(np.degrees(theta_r) + 30.0) > 3.0
    theta_r = theta_r[keep]
    tr, pr = np.abs(theta_r), np.where(theta_r >= 0, math.pi, 0.0)
    f_true = brdf(THETA_I, 0.0, tr, pr)
    print(f"sample: ρ = {SAMPLE['albedo']:g}, n(550 nm) = "
          f"{sample.truth(LAMBDA_NM)['n']:.4f}, α = {SAMPLE['alpha']}; in-plane scan "
          f"θi = 30°, {theta_r.size} points, BRDF {f_true.min():.3g} … {f_true.max():.3g} /sr "
          f"({math.log10(f_true.max() / f_true.min()):.2f} decades)")
    print(f"time per point {T_POINT_S:g} s; P_i = {P_I * 1e3:g} mW at {LAMBDA_NM:g} nm; "
          f"detectors at {DIST_MM:g} mm")
    specular = int(np.argmin(np.abs(theta_r - THETA_I)))
    _, _, info = camera_limits(tr)
    print(f"camera spot image: 1/e² radius {info['spot_radius_px']:.1f} px, ROI "
          f"{info['roi_px_at_specular']:.0f} px near specular")
    for ambient in AMBIENTS:
        cf_max, cf_min, _ = camera_limits(tr, ambient)
        rows = [("camera (sim sensor, f/4 50 mm, HDR)", cf_max, cf_min)]
        for johnson in (False, True):
            lf_max, lf_min = lockin_limits(tr, johnson=johnson, ambient=ambient)
            label = ("lock-in (SR830 sim: 10 nV/√Hz ⊕ shot)" if not johnson
                     else "lock-in ⊕ TIA Johnson noise √(4kTR_f)")
            rows.append((label, lf_max, lf_min))
        lf_max, lf_min = lockin_limits(tr, johnson=True, ambient=ambient, gain_low=1e4,
                                       gain_high=1e8)
        rows.append(("lock-in, TIA switched 1e4…1e8 V/A (+Johnson)", lf_max, lf_min))
        print(f"\nambient radiance {ambient:g} W m⁻² sr⁻¹"
              + (" (dark room)" if ambient == 0 else ""))
        print(f"{'detector':<42} {'f_max /sr':>10} {'f_min /sr':>10} {'range':>8} "
              f"{'scan pts':>9} {'scan decades':>13}")
        for label, fmax, fmin in rows:
            rng = math.log10(fmax[specular] / fmin[specular])
            n, dec = scan(f_true, fmax, fmin)
            print(f"{label:<42} {fmax[specular]:10.3g} {fmin[specular]:10.3g} {rng:7.2f}d "
                  f"{n:5d}/{theta_r.size:<3d} {dec:12.2f}d")
    print("\nrange: decades of BRDF between saturation and SNR = 3 at the specular "
          "geometry; scan: points of the in-plane scan measured (SNR ≥ 3, not saturated) "
          "and the decades they span")


if __name__ == "__main__":
    main()
