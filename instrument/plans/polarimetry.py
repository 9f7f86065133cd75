"""The polarimetry axis of a BRDF plan: a dual-rotating-retarder scan at every geometry.

A plan's ``[polarimetry]`` table::

    [polarimetry]
    mode = "drr"        # dual rotating retarder; "pem": instrument.plans.polarimetry_pem
    steps = 36          # K ≥ 16 retarder steps per geometry (default 36)
    ratio = 5           # the analyser retarder turns ratio × as far (default 5, Azzam 1978)

At each geometry (and each filter of a ``[spectral]`` axis) the plan holds K points: the
source-arm retarder's mount goes to θ_k = 180°·k/K and the detector-arm retarder's to
ratio·θ_k (:func:`analysis.polarimetry.drr.drr_angles`), both commanded modulo 360° (a
retarder's Mueller matrix repeats every 180°, so one turn of travel is enough) and moved
together by the engine's move of the point; the polarisers' mounts stay at 0, where the
profile's ``[optics]`` puts their nominal axes. Each point carries ``drr_step`` = k in its
meta; the run file keeps the mounts' read-back angles in its positions table and the
profile's ``[optics]`` (the nominal train) in the stored profile.

The instrument matrix of the chosen steps and the profile's nominal retardances has a
condition number κ (Smith 2002, Appl. Opt. 41, 2488) that bounds how much the
intensities' noise grows in the Mueller matrix; :func:`conditioning` gives it with the
optimum retardance for the same steps, and a warning where κ is more than
:data:`FAR_FROM_OPTIMUM` times the optimum's. For 16 to 24 steps (except 23) the equal
steps alias and W is singular: such a plan is refused.

PEM mode (a photoelastic modulator read by the lock-in at 1f and 2f at fixed generator
and analyser settings) is parsed, judged and expanded by
:mod:`instrument.plans.polarimetry_pem`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from instrument.bench.optics import OpticalTrain
from instrument.bench.profile import BenchProfile, FieldError, _Validator
from instrument.plans.commands import ScanPoint
from instrument.plans.errors import PlanError
from instrument.plans.mount_limits import check_mount_limits

__all__ = ["DEFAULT_STEPS", "FAR_FROM_OPTIMUM", "MIN_STEPS", "POLARIMETRY_KINDS", "Conditioning",
           "conditioning", "parse_polarimetry", "plan_wavelengths", "polarimetry_axis"]

DEFAULT_STEPS = 36
MIN_STEPS = 16
MAX_STEPS = 720
#: κ above this multiple of the optimum retardance's κ (same steps) earns a warning.
FAR_FROM_OPTIMUM = 2.0
#: Plan kinds that take a polarimetry axis.
POLARIMETRY_KINDS = ("brdf_in_plane", "brdf_hemisphere")
#: The retardances (degrees) searched for the optimum.
_SEARCH_DEG = tuple(range(30, 181))


def parse_polarimetry(v: _Validator, t: Any, kind: str | None) -> dict[str, Any] | None:
    """``[polarimetry]`` (errors recorded on ``v``), as ``{mode, steps, ratio}``."""
    if t is None:
        return None
    if not isinstance(t, dict):
        v.error("polarimetry", "must be a table (mode, steps, ratio)")
        return None
    if kind is not None and kind not in POLARIMETRY_KINDS:
        v.error("polarimetry", f"a {kind} plan has no polarimetry axis; only "
                f"{', '.join(POLARIMETRY_KINDS)} plans take one")
    mode = t.get("mode", "drr")
    if mode == "pem":
        from instrument.plans.polarimetry_pem import parse_pem

        return parse_pem(v, t)
    v.unknown(t, "polarimetry", {"mode", "steps", "ratio"})
    if mode != "drr":
        v.error("polarimetry.mode", f"must be \"drr\" (dual rotating retarder) or \"pem\" "
                f"(a photoelastic modulator read at 1f and 2f), got {mode!r}")
    steps = t.get("steps", DEFAULT_STEPS)
    if (not isinstance(steps, int) or isinstance(steps, bool)
            or not MIN_STEPS <= steps <= MAX_STEPS):
        v.error("polarimetry.steps", f"must be an integer from {MIN_STEPS} (16 unknown "
                f"Mueller elements) to {MAX_STEPS}, got {steps!r}")
        steps = DEFAULT_STEPS
    ratio = t.get("ratio", 5)
    if (not isinstance(ratio, int | float) or isinstance(ratio, bool)
            or not math.isfinite(ratio) or not 1 < abs(ratio) <= 20):
        v.error("polarimetry.ratio", f"must be a number with 1 < |ratio| ≤ 20 (5 is "
                f"Azzam's), got {ratio!r}")
        ratio = 5
    return {"mode": "drr", "steps": int(steps), "ratio": float(ratio)}


@dataclass(frozen=True)
class Conditioning:
    """How well a DRR scan determines the Mueller matrix at one wavelength."""

    wavelength_nm: float | None
    psg_retardance_deg: float
    psa_retardance_deg: float
    kappa: float
    optimum_kappa: float
    optimum_retardance_deg: float

    @property
    def far_from_optimum(self) -> bool:
        return not self.kappa <= FAR_FROM_OPTIMUM * self.optimum_kappa

    def describe(self) -> str:
        where = "" if self.wavelength_nm is None else f" at {self.wavelength_nm:g} nm"
        return (f"condition number κ = {self.kappa:.3g}{where} (retardances "
                f"{self.psg_retardance_deg:g}° / {self.psa_retardance_deg:g}°); the optimum "
                f"for these steps is κ = {self.optimum_kappa:.3g} at "
                f"{self.optimum_retardance_deg:g}°")


def _kappa(steps: int, ratio: float, psg_deg: float, psa_deg: float,
           extinction: dict[str, float] | None = None) -> float:
    from analysis.polarimetry.drr import condition_number, drr_angles, instrument_matrix

    g, a = drr_angles(steps, ratio)
    w = instrument_matrix(g, a, psg_retardance=math.radians(psg_deg),
                          psa_retardance=math.radians(psa_deg), **(extinction or {}))
    return condition_number(w)


def _train(profile: BenchProfile) -> OpticalTrain:
    """The profile's train with a retarder on a mount in each arm, or a PlanError."""

    optics = profile.optics
    problems = []
    if optics is None:
        problems.append(FieldError("polarimetry", f"bench {profile.name!r} names no optical "
                                   "train: a polarimetric plan needs the profile's [optics] "
                                   "with a retarder on a rotation mount in each arm"))
    else:
        for arm in ("source", "detector"):
            element = optics.retarder(arm)
            if element is None or element.mount is None:
                problems.append(FieldError("polarimetry", f"bench {profile.name!r} has no "
                                           f"retarder on a mount in its {arm} arm "
                                           f"([[optics.{arm}]] with kind = \"retarder\")"))
    if problems:
        raise PlanError(f"bench {profile.name!r}", problems)
    assert optics is not None
    return optics


def plan_wavelengths(profile: BenchProfile, filters: Sequence[float] | None) -> list[float]:
    """The wavelengths (nm) a plan's light has: its filters' centres, else the simulated
    source's or the power meter's setting; empty when the profile does not say."""
    if filters:
        return [float(x) for x in filters]
    src = dict((profile.simulation or {}).get("source", {}))
    if "wavelength_nm" in src:
        return [float(src["wavelength_nm"])]
    for d in profile.devices.values():
        if d.kind == "power_meter" and "wavelength_nm" in d.settings:
            return [float(d.settings["wavelength_nm"])]
    return []


def conditioning(pol: dict[str, Any], profile: BenchProfile,
                 wavelengths: Sequence[float] = ()) -> list[Conditioning]:
    """κ of the plan's steps with the profile's nominal retardances, per wavelength (one
    entry without any), with the optimum common retardance for the same steps."""
    train = _train(profile)
    psg, psa = train.retarder("source"), train.retarder("detector")
    assert psg is not None and psa is not None  # _train checked
    steps, ratio = int(pol["steps"]), float(pol["ratio"])
    kappas = [(_kappa(steps, ratio, d, d), d) for d in _SEARCH_DEG]
    best_kappa, best_deg = min(kappas)
    out = []
    at_wavelengths: list[float | None] = [*wavelengths] or [None]
    for lam in at_wavelengths:
        at = 550.0 if lam is None else lam
        dg, da = psg.retardance_at(at), psa.retardance_at(at)
        out.append(Conditioning(lam, dg, da, _kappa(steps, ratio, dg, da,
                                                    train.extinctions()), best_kappa,
                                float(best_deg)))
    return out


def polarimetry_axis(pol: dict[str, Any], profile: BenchProfile, body: list[ScanPoint],
                     wavelengths: Sequence[float] = ()) -> list[ScanPoint]:
    """Each lit point of ``body`` as ``steps`` points with the retarders' mounts at θ_k
    and ratio·θ_k (modulo 360°) and the polarisers' at 0; dark points stay as they are.

    Raises
    ------
    PlanError
        The profile has no retarder in an arm, a mount's limits do not hold a turn, or the
        steps make the instrument matrix singular.
    """
    from analysis.polarimetry.drr import drr_angles

    train = _train(profile)
    steps, ratio = int(pol["steps"]), float(pol["ratio"])
    for c in conditioning(pol, profile, wavelengths):
        if not math.isfinite(c.kappa):
            raise PlanError(f"bench {profile.name!r}", [FieldError(
                "polarimetry.steps", f"{steps} equal steps at ratio {ratio:g} make the "
                "instrument matrix singular (its harmonics alias): use 23 or ≥ 25 steps")])
    theta_g, theta_a = drr_angles(steps, ratio)
    psg, psa = train.retarder("source"), train.retarder("detector")
    assert psg is not None and psa is not None and psg.mount and psa.mount
    fixed = tuple((e.mount, 0.0) for e in (*train.source, *train.detector)
                  if e.kind == "polariser" and e.mount is not None)
    moves = [((psg.mount, float(g % 360.0)), (psa.mount, float(a % 360.0)))
             for g, a in zip(theta_g, theta_a, strict=True)]
    check_mount_limits(profile, [dict((*fixed, *m)) for m in moves])
    out: list[ScanPoint] = []
    for p in body:
        if not p.light:
            out.append(p)
            continue
        for k, move in enumerate(moves):
            out.append(replace(p, targets=(*p.targets, *fixed, *move),
                               meta=(*p.meta, ("drr_step", k))))
    return out
