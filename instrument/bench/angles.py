"""How well a run's recorded angles are known: the angular error model of the stages.

A run stores the angles computed from the axes' *read-back* positions, not from their
targets: how far an axis stopped from its target (``position_tolerance``) is already in
the data and is no error of the recorded angle. What remains is how well the read-back
tells where the stage really is:

* **read-back resolution** ``readback_resolution`` (axis units): the quantum of the
  position counter; a uniform rounding error, σ = q/√12 (GUM JCGM 100:2008, §F.2.2.1);
* **repeatability** ``repeatability`` (axis units, the ± half-width of the spec sheet's
  bidirectional repeatability): where the load is, for one read-back, from one approach to
  the next (backlash, a motor encoder behind a worm gear); rectangular, σ = r/√3 (GUM
  §4.3.7).

Both are keys of a motion device in the bench profile. Without them, defaults by driver
kind: the resolution from the controller's counts per unit (Thorlabs APT stages:
``drivers.thorlabs_apt.STAGES``, e.g. K10CR1 409600 µsteps per 3°); the
repeatability of an emulated stage (``sim…`` URLs) is 0, since its read-back *is* the
simulated world's position; a real stage without a declared repeatability is reported
as unknown (taken as 0, with a warning naming the key to set).

In plane (ADR 0012) θi is the source's angle less the sample stage's and θr the
detector arm's less the sample stage's: σθi = σ_sample, σθr = σ_sample ⊕ σ_arm (the
sample stage's error shifts both; their correlation is left out). On a type (i)
goniometer (ADR 0099) the sample stands still and θi, θr are the arcs' own angles:
σθi = σ_source_arc, σθr = σ_detector_arc (the azimuth stages move φ, not θ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from drivers.thorlabs_apt import STAGES

__all__ = ["AngularModel", "StageAngle", "angular_model", "stage_angle"]



@dataclass(frozen=True)
class StageAngle:
    """The read-back error of one stage (axis units) and where each number came from."""

    role: str
    resolution: float
    repeatability: float | None
    source: str

    @property
    def sigma(self) -> float:
        """Standard uncertainty of one read-back (axis units): q/√12 ⊕ r/√3."""
        rep = self.repeatability or 0.0
        return math.hypot(self.resolution / math.sqrt(12.0), rep / math.sqrt(3.0))


@dataclass(frozen=True)
class AngularModel:
    """σθi and σθr (radians) of the recorded angles, the stages behind them, and the
    warnings (a repeatability nobody declared)."""

    sigma_theta_i_rad: float
    sigma_theta_r_rad: float
    stages: tuple[StageAngle, ...]
    warnings: tuple[str, ...]

    def describe(self) -> str:
        parts = [f"{s.role}: {s.source}" for s in self.stages]
        return (f"σθi = {math.degrees(self.sigma_theta_i_rad):.2g}°, σθr = "
                f"{math.degrees(self.sigma_theta_r_rad):.2g}° from the read-back ("
                + "; ".join(parts) + ")")


def stage_angle(role: str, device: dict[str, Any]) -> StageAngle:
    """The read-back error of the motion device ``device`` (its profile table) in role
    ``role`` (module docstring)."""
    res = device.get("readback_resolution")
    rep = device.get("repeatability")
    src = []
    if res is None:
        stage = STAGES.get(str(device.get("stage")))
        cpu = (stage.counts_per_unit if stage is not None
               and device.get("driver") == "thorlabs_apt" else None)
        res = 1.0 / cpu if cpu else 0.0
        src.append(f"resolution {res:.2g} from the {device.get('stage')} counts"
                   if cpu else "resolution not declared (0)")
    else:
        src.append(f"resolution {float(res):g} (profile)")
    if rep is None and str(device.get("url", "")).startswith("sim"):
        rep = 0.0
        src.append("repeatability 0 (emulated stage: the read-back is the world's position)")
    elif rep is None:
        src.append("repeatability unknown")
    else:
        src.append(f"repeatability ±{float(rep):g} (profile)")
    return StageAngle(role, float(res), None if rep is None else float(rep), ", ".join(src))


def angular_model(profile: dict[str, Any]) -> AngularModel:
    """σθi, σθr of the recorded angles of a run with the bench profile ``profile`` (the
    parsed TOML stored in the run; module docstring)."""
    devices = profile.get("devices", {})
    type_i = profile.get("geometry", {}).get("goniometer") == "type_i"
    roles = ("source_arc", "detector_arc") if type_i else ("sample_theta", "detector_theta")
    stages = tuple(stage_angle(r, devices[r]) for r in roles if r in devices)
    sig = {s.role: math.radians(s.sigma) for s in stages}
    warnings = tuple(
        f"{s.role}: the stage's repeatability is not declared, so the angles' uncertainty "
        "holds the read-back resolution only; set devices."
        f"{s.role}.repeatability (± in axis units, from the spec sheet or measured)"
        for s in stages if s.repeatability is None)
    if type_i:
        return AngularModel(sig.get("source_arc", 0.0), sig.get("detector_arc", 0.0), stages,
                            warnings)
    s_sample = sig.get("sample_theta", 0.0)
    return AngularModel(s_sample, math.hypot(s_sample, sig.get("detector_theta", 0.0)),
                        stages, warnings)
