"""Typed plan commands and the per-point acquisition policy.

A plan is a generator of these frozen dataclasses; the engine executes them with a
``match`` on the class. A point's commands are always
``Move → Acquire → PointDone``, optionally preceded by ``SetLight``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from instrument.bench.kinematics import Angles

__all__ = [
    "Acquire",
    "AcquisitionPolicy",
    "Command",
    "Move",
    "PointDone",
    "ScanPoint",
    "SetLight",
]

#: Labels a point may carry (what the frames at that point are).
LABELS = ("sample", "dark", "reference", "signature", "flat", "ptc", "lightfield", "sphere")
DARK_POLICIES = ("none", "per_point", "per_row", "start")
MODES = ("fixed", "auto")
DETECTORS = ("camera", "power_meter", "lockin")


@dataclass(frozen=True)
class AcquisitionPolicy:
    """How each point is acquired; stored verbatim (JSON) in every run file.

    ``mode="fixed"`` takes ``frames`` frames at ``exposure_us`` and averages them.
    ``mode="auto"`` starts from the last exposure used (first point: ``exposure_us``),
    shortens it by ``hdr_factor`` while any pixel saturates and lengthens it while the
    brightest pixel is below ``target_fraction``/``hdr_factor`` of saturation; with
    ``hdr=true`` every saturated bracket is kept as well (down to ``max_brackets``
    exposures), so an HDR merge can use them. ``dark`` chooses when dark frames (light
    off) are taken: never, after every point at the same exposure(s), before every row of
    θi (a dark point where the axes are), or once at the start of the run; the power meter
    and the lock-in read their dark at the same times as the camera. ``dark_detectors``
    names the detectors whose per-point dark is read (``None``: every detector listed);
    a plan that leaves ``detectors`` at its default measures with the camera and reads
    the power meter beside it without a dark of its own (:meth:`reads_dark`).
    ``spin_deg_s`` > 0 spins the sample about its normal at that rate through the run
    (the bench's ``sample_spin`` stage), so that an exposure averages a laser's speckle
    over the patterns it sweeps (ADR 0098); 0 keeps the sample still.
    """

    mode: str = "fixed"
    exposure_us: float = 10000.0
    min_exposure_us: float = 10.0
    max_exposure_us: float = 2.0e6
    target_fraction: float = 0.7
    hdr: bool = False
    hdr_factor: float = 8.0
    max_brackets: int = 4
    frames: int = 1
    dark: str = "none"
    detectors: tuple[str, ...] = ("camera", "power_meter")
    readout_s: float = 0.0  # per-frame readout/transfer overhead, for estimates only
    dark_detectors: tuple[str, ...] | None = None
    spin_deg_s: float = 0.0

    def as_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @property
    def uses_camera(self) -> bool:
        return "camera" in self.detectors

    @property
    def uses_power_meter(self) -> bool:
        return "power_meter" in self.detectors

    @property
    def uses_lockin(self) -> bool:
        return "lockin" in self.detectors

    def reads_dark(self, detector: str) -> bool:
        """Whether ``detector`` reads its own dark at each point under ``dark="per_point"``
        (a detector the plan does not read never does)."""
        if detector not in self.detectors:
            return False
        return self.dark_detectors is None or detector in self.dark_detectors

    def estimated_seconds(self, exposure_us: float | None = None) -> float:
        """Time one point's acquisition takes (no brackets), for dry-run estimates."""
        if not self.uses_camera:
            return 0.0
        e = (exposure_us if exposure_us is not None else self.exposure_us) * 1e-6
        n = self.frames * (2 if self.dark == "per_point" else 1)
        return n * (e + self.readout_s)


@dataclass(frozen=True)
class ScanPoint:
    """One point of a plan: where the axes go and what is acquired there.

    ``index`` is the point's position in execution order (the row in the run file);
    ``targets`` are axis positions by role; ``angles`` is ``None`` for points without a
    scattering geometry (dark frames, light-field positions).
    """

    index: int
    targets: tuple[tuple[str, float], ...]
    angles: Angles | None = None
    label: str = "sample"
    light: bool = True
    exposure_us: float | None = None  # overrides the policy (dark/PTC sweeps)
    meta: tuple[tuple[str, Any], ...] = field(default=())

    def target_dict(self) -> dict[str, float]:
        return dict(self.targets)

    def describe(self) -> str:
        parts = [f"{r}={v:.4g}" for r, v in self.targets]
        if self.angles is not None:
            a = self.angles
            parts.insert(0, f"θi={a.theta_i:.4g} φi={a.phi_i:.4g} θr={a.theta_r:.4g} "
                         f"φr={a.phi_r:.4g}")
        return f"{self.label} " + " ".join(parts)


@dataclass(frozen=True)
class SetLight:
    on: bool


@dataclass(frozen=True)
class Move:
    index: int
    targets: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class Acquire:
    index: int
    policy: AcquisitionPolicy
    label: str
    light: bool
    exposure_us: float | None = None


@dataclass(frozen=True)
class PointDone:
    index: int


Command = SetLight | Move | Acquire | PointDone
