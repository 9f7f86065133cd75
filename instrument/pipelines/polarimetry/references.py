"""Reference runs (air, a polariser, a retarder, straight through) → a polarimeter
calibration.

Each reference run is a dual-rotating-retarder scan at one position with the detector arm
in the straight-through beam. Its readings become an
:class:`analysis.polarimetry.calibration.ReferenceScan` (the retarders' axes as the
readings module gives them: nominal orientation plus read-back position), and
:func:`analysis.polarimetry.calibration.calibrate_drr` fits the five instrument parameters
with the references' own azimuths and retardances as nuisance parameters. The air scan's
fitted scale is the unit-source intensity that turns a reduced matrix into a
transmittance (or, divided by Ω cos θr, a BRDF).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from analysis.polarimetry.calibration import ReferenceScan, calibrate_drr
from instrument.pipelines.polarimetry.calibration import PolarimeterCalibration, now, quality
from instrument.pipelines.polarimetry.readings import read_polarimetric

__all__ = ["ReferenceRun", "calibrate_from_runs"]


@dataclass(frozen=True)
class ReferenceRun:
    """A reference run and what it holds: ``kind`` (``air``, ``polariser``, ``retarder``),
    the nominal azimuth (deg) and, for a retarder, the nominal retardance (deg)."""

    path: Path
    kind: str
    angle_deg: float = 0.0
    retardance_deg: float = 90.0


def _scan(ref: ReferenceRun) -> tuple[ReferenceScan, dict[str, float], str]:
    """The run's scan, the nominal optics the fit starts from or holds (retardances in
    radians, the polarisers' datasheet extinctions) and the bench's name."""
    prun = read_polarimetric(ref.path)
    if len(prun.groups) != 1:
        raise ValueError(f"{ref.path}: a reference run holds one straight-through position, "
                         f"this one {len(prun.groups)}")
    g = prun.groups[0]
    scan = ReferenceScan(kind=ref.kind, intensities=g.intensity, sigmas=g.sigma,
                         psg_retarder_deg=g.psg_retarder_deg,
                         psa_retarder_deg=g.psa_retarder_deg, angle_deg=ref.angle_deg,
                         retardance=math.radians(ref.retardance_deg))
    bench = str(prun.run.profile().get("bench", {}).get("name", ""))
    nominal = {"psg_retardance": math.radians(prun.retardance_deg("psg", g.wavelength_nm)),
               "psa_retardance": math.radians(prun.retardance_deg("psa", g.wavelength_nm)),
               "psg_extinction": prun.extinction("psg"),
               "psa_extinction": prun.extinction("psa")}
    return scan, nominal, bench


def calibrate_from_runs(refs: Sequence[ReferenceRun], *, bench: str | None = None
                        ) -> PolarimeterCalibration:
    """Fit the calibration to the reference runs (module docstring).

    Raises
    ------
    ValueError
        No air run, runs of different benches, or a run that is not a one-position
        polarimetric scan.
    """
    if not any(r.kind == "air" for r in refs):
        raise ValueError("the calibration needs an air run (no sample, straight through)")
    scans, benches, trains = [], set(), []
    for r in refs:
        scan, nominal, b = _scan(r)
        scans.append(scan)
        benches.add(b)
        trains.append(nominal)
    if len(benches) != 1:
        raise ValueError(f"the reference runs were taken on different benches {benches}")
    drr = calibrate_drr(scans, **trains[-1])
    air = next(k for k, r in enumerate(refs) if r.kind == "air")
    ok, why = quality(drr)
    return PolarimeterCalibration(
        drr=drr, bench=bench or benches.pop(), source_scale_w=float(drr.sample_params[air][0]),
        date=now(), valid=ok, quality=why,
        references=tuple({"kind": r.kind, "run": str(Path(r.path).resolve()),
                          "angle_deg": r.angle_deg,
                          **({"retardance_deg": r.retardance_deg} if r.kind == "retarder"
                             else {})} for r in refs))
