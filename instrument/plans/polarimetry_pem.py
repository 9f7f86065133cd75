"""PEM mode of a plan's polarimetry axis: fixed generator and analyser settings, the
photoelastic modulator's 1f and 2f read by the lock-in at every setting.

A plan's ``[polarimetry]`` table in PEM mode::

    [polarimetry]
    mode = "pem"
    amplitude_waves = 0.3828        # the modulator's peak retardation (default: the
                                    # profile's pem setting; 0.3828 waves = 2.405 rad)
    generator_deg = [0.0, 45.0]     # the source polariser's settings (element axes)
    analyser_deg = [-75.0, -37.5, 37.5, 75.0]  # the analyser retarder's settings
    time_constants = 15             # settle before each harmonic, in lock-in τ
    reads = 6                       # snapshots per harmonic (their scatter is σ)

At each geometry (and each filter of a ``[spectral]`` axis) the plan holds one point per
setting, generator-major (the analyser's settings taken back and forth)
(:func:`analysis.polarimetry.pem.pem_settings`: two generator by four analyser settings
are the minimal set that determines all 16 elements, ADR 0105): the source polariser's
mount at the generator angle, the analyser retarder's at the analyser angle (each less the
element's nominal ``orientation_deg``), the analyser polariser's, if it is mounted, at 0.
Each point carries ``pem_setting`` (its index) and ``pem_waves`` (the amplitude the engine
sets) in its meta; the engine then reads the lock-in's Aux In 1 (the photodiode's DC) and
harmonics 1 and 2 (:mod:`instrument.run.engine`).

The bench must have the optical train of such a polarimeter (a polariser on a mount before
a ``kind = "pem"`` element in the source arm, a retarder on a mount in the detector arm), a
modulator device and a lock-in, and the plan must read the lock-in (``detectors =
["lockin"]``); anything missing is a :class:`~instrument.plans.errors.PlanError` naming the
field and what to do.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from instrument.bench.optics import OpticalElement, OpticalTrain
from instrument.bench.profile import BenchProfile, FieldError, _Validator
from instrument.plans.commands import AcquisitionPolicy, ScanPoint
from instrument.plans.errors import PlanError
from instrument.plans.mount_limits import check_mount_limits

__all__ = ["DEFAULT_READS", "DEFAULT_TIME_CONSTANTS", "PEM_KEYS", "PemConditioning",
           "PemTrain", "parse_pem", "pem_axis", "pem_conditioning", "pem_train",
           "plan_settings", "plan_waves"]

#: The lock-in settles this many time constants before each harmonic: the default 99 %
#: wait leaves 1 % of the 1f–2f step in the reading, a 10⁻³ bias (ADR 0105).
DEFAULT_TIME_CONSTANTS = 15.0
#: Snapshots per harmonic; their scatter is each reading's σ.
DEFAULT_READS = 6
#: The amplitude (waves) where J₀(A) = 0 (A = 2.405 rad), used when neither the plan nor
#: the profile's modulator settings give one.
DEFAULT_WAVES = 2.405 / (2.0 * math.pi)
PEM_KEYS = {"mode", "amplitude_waves", "generator_deg", "analyser_deg", "time_constants",
            "reads"}


def _angles(v: _Validator, t: dict[str, Any], key: str, default: Sequence[float],
            at_least: int) -> list[float]:
    value = t.get(key, list(default))
    ok = (isinstance(value, list) and len(value) >= at_least
          and all(isinstance(x, int | float) and not isinstance(x, bool)
                  and math.isfinite(x) and -180.0 <= x <= 180.0 for x in value))
    if not ok:
        v.error(f"polarimetry.{key}", f"must be a list of at least {at_least} angles "
                f"(degrees, −180 to 180), got {value!r}")
        return [float(x) for x in default]
    return [float(x) for x in value]


def parse_pem(v: _Validator, t: dict[str, Any]) -> dict[str, Any]:
    """``[polarimetry]`` with ``mode = "pem"`` (errors recorded on ``v``)."""
    from analysis.polarimetry.pem import (
        DEFAULT_ANALYSER_RETARDER_DEG,
        DEFAULT_GENERATOR_POLARISER_DEG,
    )

    for key in ("steps", "ratio"):
        if key in t:
            v.error(f"polarimetry.{key}", "belongs to a dual rotating retarder (mode = "
                    "\"drr\"); a PEM scan takes generator_deg and analyser_deg")
    v.unknown(t, "polarimetry", PEM_KEYS | {"steps", "ratio"})
    waves = t.get("amplitude_waves")
    if waves is not None and (not isinstance(waves, int | float) or isinstance(waves, bool)
                              or not 0.05 <= waves <= 1.0):
        v.error("polarimetry.amplitude_waves", f"must be a peak retardation from 0.05 to 1 "
                f"wave (0.3828 puts J₀ at zero), got {waves!r}")
        waves = None
    tau = t.get("time_constants", DEFAULT_TIME_CONSTANTS)
    if (not isinstance(tau, int | float) or isinstance(tau, bool) or not math.isfinite(tau)
            or not 1.0 <= tau <= 100.0):
        v.error("polarimetry.time_constants", f"must be a number of lock-in time constants "
                f"from 1 to 100 (15 leaves 3e-7 of a step), got {tau!r}")
        tau = DEFAULT_TIME_CONSTANTS
    reads = t.get("reads", DEFAULT_READS)
    if not isinstance(reads, int) or isinstance(reads, bool) or not 4 <= reads <= 100:
        v.error("polarimetry.reads", f"must be an integer from 4 to 100 (snapshots per "
                f"harmonic; their scatter is the reading's σ), got {reads!r}")
        reads = DEFAULT_READS
    return {"mode": "pem", "amplitude_waves": None if waves is None else float(waves),
            "generator_deg": _angles(v, t, "generator_deg", DEFAULT_GENERATOR_POLARISER_DEG, 2),
            "analyser_deg": _angles(v, t, "analyser_deg", DEFAULT_ANALYSER_RETARDER_DEG, 4),
            "time_constants": float(tau), "reads": int(reads)}


@dataclass(frozen=True)
class PemTrain:
    """The elements a PEM scan sets: the source polariser and the modulator, the analyser
    retarder and (optional) polariser, with the bench's modulator and lock-in roles."""

    polariser: OpticalElement
    pem: OpticalElement
    retarder: OpticalElement
    analyser: OpticalElement | None
    modulator_role: str
    lockin_role: str


def _first(elements: Sequence[OpticalElement], kind: str) -> OpticalElement | None:
    return next((e for e in elements if e.kind == kind), None)


def pem_train(profile: BenchProfile) -> PemTrain:
    """The profile's PEM polarimeter, or a PlanError naming every missing part."""
    where = f"bench {profile.name!r}"
    optics: OpticalTrain | None = profile.optics
    problems: list[FieldError] = []
    roles = {kind: next((r for r, d in profile.devices.items() if d.kind == kind), None)
             for kind in ("modulator", "lockin")}
    if roles["modulator"] is None:
        problems.append(FieldError("polarimetry.mode", f"{where} has no modulator device: "
                                   "PEM mode needs a photoelastic modulator's controller "
                                   "(e.g. driver = \"pem200\"); use mode = \"drr\" on a "
                                   "dual-rotating-retarder bench"))
    if roles["lockin"] is None:
        problems.append(FieldError("polarimetry.mode", f"{where} has no lock-in: PEM mode "
                                   "reads the photodiode at 1f and 2f with one (e.g. driver "
                                   "= \"sr830\", REF IN from the modulator)"))
    source = optics.source if optics is not None else ()
    detector = optics.detector if optics is not None else ()
    pol, pem = _first(source, "polariser"), _first(source, "pem")
    ret, ana = _first(detector, "retarder"), _first(detector, "polariser")
    if pem is None:
        problems.append(FieldError("polarimetry.mode", f"{where} names no PEM in its "
                                   "optical train: add [[optics.source]] kind = \"pem\" "
                                   "with its orientation_deg (45° to the polariser)"))
    if pol is None or pol.mount is None or (pem is not None
                                           and source.index(pol) > source.index(pem)):
        problems.append(FieldError("polarimetry.mode", f"{where} has no polariser on a "
                                   "mount before the PEM in its source arm ([[optics."
                                   "source]] kind = \"polariser\" with a mount)"))
    if ret is None or ret.mount is None:
        problems.append(FieldError("polarimetry.mode", f"{where} has no retarder on a mount "
                                   "in its detector arm ([[optics.detector]] kind = "
                                   "\"retarder\" with a mount): the analyser must sense V"))
    if problems:
        raise PlanError(where, problems)
    assert pol is not None and pem is not None and ret is not None
    assert roles["modulator"] is not None and roles["lockin"] is not None
    return PemTrain(pol, pem, ret, ana, roles["modulator"], roles["lockin"])


def plan_waves(pol: dict[str, Any], profile: BenchProfile, train: PemTrain) -> float:
    """The amplitude (waves at the modulator's wavelength): the plan's, else the profile's
    modulator setting, else the J₀ zero."""
    if pol.get("amplitude_waves") is not None:
        return float(pol["amplitude_waves"])
    spec = profile.devices[train.modulator_role]
    return float(spec.settings.get("retardation_waves", DEFAULT_WAVES))


def _pem_wavelength(profile: BenchProfile, train: PemTrain) -> float | None:
    value = profile.devices[train.modulator_role].settings.get("wavelength_nm")
    return None if value is None else float(value)


def plan_settings(pol: dict[str, Any], train: PemTrain) -> list[Any]:
    """The plan's :class:`~analysis.polarimetry.pem.PemSetting` list (element axes),
    generator-major, at the nominal orientations of the modulator and analyser polariser."""
    from analysis.polarimetry.pem import pem_settings

    return list(pem_settings(pol["generator_deg"], pol["analyser_deg"],
                             pem_axis_deg=train.pem.orientation_deg,
                             analyser_polariser_deg=(0.0 if train.analyser is None
                                                     else train.analyser.orientation_deg)))


@dataclass(frozen=True)
class PemConditioning:
    """How well the PEM settings determine the Mueller matrix at one wavelength."""

    wavelength_nm: float | None
    amplitude_rad: float
    analyser_retardance_deg: float
    kappa: float

    def describe(self) -> str:
        where = "" if self.wavelength_nm is None else f" at {self.wavelength_nm:g} nm"
        return (f"condition number κ = {self.kappa:.3g}{where} (PEM amplitude "
                f"{self.amplitude_rad:.3f} rad, analyser retardance "
                f"{self.analyser_retardance_deg:g}°)")


def pem_conditioning(pol: dict[str, Any], profile: BenchProfile,
                     wavelengths: Sequence[float] = ()) -> list[PemConditioning]:
    """κ of the stacked DC/1f/2f instrument matrix per wavelength (one entry without any):
    the modulator's amplitude in radians scales as its wavelength setting over the
    light's (a retardation in nm is fixed by the drive)."""
    from analysis.polarimetry.pem import pem_condition_number

    train = pem_train(profile)
    settings = plan_settings(pol, train)
    waves = plan_waves(pol, profile, train)
    at_pem = _pem_wavelength(profile, train)
    assert profile.optics is not None  # pem_train checked
    extinction = profile.optics.extinctions()
    out = []
    at_wavelengths: list[float | None] = [*wavelengths] or [None]
    for lam in at_wavelengths:
        ratio = 1.0 if lam is None or at_pem is None else at_pem / lam
        amp = 2.0 * math.pi * waves * ratio
        ret = train.retarder.retardance_at(550.0 if lam is None else lam)
        kappa = pem_condition_number(settings, amplitude_rad=amp,
                                     analyser_retardance_rad=math.radians(ret), **extinction)
        out.append(PemConditioning(lam, amp, ret, kappa))
    return out


def pem_axis(pol: dict[str, Any], profile: BenchProfile, body: list[ScanPoint],
             acquisition: AcquisitionPolicy, wavelengths: Sequence[float] = ()
             ) -> list[ScanPoint]:
    """Each lit point of ``body`` as one point per PEM setting (module docstring); dark
    points stay as they are.

    Raises
    ------
    PlanError
        The bench is not a PEM polarimeter, the plan does not read the lock-in, a mount's
        limits do not hold its settings, or the settings miss some elements.
    """
    train = pem_train(profile)
    if tuple(acquisition.detectors) != ("lockin",):
        raise PlanError(f"bench {profile.name!r}", [FieldError(
            "acquisition.detectors", f"PEM mode reads the lock-in only (DC on its Aux In 1, "
            f"1f and 2f by harmonic): set detectors = [\"lockin\"], got "
            f"{list(acquisition.detectors)}")])
    if acquisition.dark == "per_point":
        raise PlanError(f"bench {profile.name!r}", [FieldError(
            "acquisition.dark", "PEM mode takes no per-point dark (1f and 2f are AC "
            "signals; the DC's offset is an Aux In zero): use dark = \"none\"")])
    for c in pem_conditioning(pol, profile, wavelengths):
        if not math.isfinite(c.kappa) or c.kappa > 1e6:
            raise PlanError(f"bench {profile.name!r}", [FieldError(
                "polarimetry.analyser_deg", f"these settings do not determine all 16 "
                f"elements (κ = {c.kappa:.3g}): give four analyser angles whose rows span "
                "the Stokes space, e.g. the default [-75, -37.5, 37.5, 75]")])
    waves = plan_waves(pol, profile, train)
    settings = plan_settings(pol, train)
    assert train.polariser.mount is not None and train.retarder.mount is not None
    fixed: tuple[tuple[str, float], ...] = ()
    if train.analyser is not None and train.analyser.mount is not None:
        fixed = ((train.analyser.mount, 0.0),)
    moves = [((train.polariser.mount, s.polariser_deg - train.polariser.orientation_deg),
              (train.retarder.mount,
               s.analyser_retarder_deg - train.retarder.orientation_deg))
             for s in settings]
    check_mount_limits(profile, [dict((*fixed, *m)) for m in moves])
    # the analyser's settings back and forth (a snake): one turn less per generator setting
    n_a = len(pol["analyser_deg"])
    order = [g * n_a + (a if g % 2 == 0 else n_a - 1 - a)
             for g in range(len(pol["generator_deg"])) for a in range(n_a)]
    out: list[ScanPoint] = []
    for p in body:
        if not p.light:
            out.append(p)
            continue
        for k in order:
            out.append(replace(p, targets=(*p.targets, *fixed, *moves[k]),
                               meta=(*p.meta, ("pem_setting", k), ("pem_waves", waves))))
    return out
