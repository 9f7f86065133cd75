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

PEM reference runs (``[polarimetry] mode = "pem"``, one straight-through position each)
become :class:`analysis.polarimetry.pem_calibration.PemReferenceScan` and are fitted by
:func:`analysis.polarimetry.pem_calibration.calibrate_pem` (ADR 0113): the same
references, the PEM train's five parameters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.polarimetry.calibration import ReferenceScan, calibrate_drr
from analysis.polarimetry.pem_calibration import PemReferenceScan, calibrate_pem
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


def _scan(ref: ReferenceRun) -> tuple[ReferenceScan | PemReferenceScan, dict[str, float],
                                       str]:
    """The run's scan (a PEM run's as a PEM scan), the nominal optics the fit starts from
    or holds (retardances in radians, the polarisers' datasheet extinctions) and the
    bench's name."""
    prun = read_polarimetric(ref.path)
    if len(prun.groups) != 1:
        raise ValueError(f"{ref.path}: a reference run holds one straight-through position, "
                         f"this one {len(prun.groups)}")
    g = prun.groups[0]
    scan: ReferenceScan | PemReferenceScan
    if g.pem is not None:
        # a reference run's eight points do not determine the lock-in's pooled noise model
        # (readings over three decades, each harmonic at its own range): with it alone the
        # calibration's χ²/dof ranged 1.0–3.1 over seeds. Each point's own standard error
        # over its snapshots bounds σ from below.
        sigmas = g.pem.sigmas.copy()
        for col, name in ((1, "pem_u_1f_v"), (2, "pem_u_2f_v")):
            own = prun.run.detectors.get(name)
            if own is not None:
                sigmas[:, col] = np.maximum(sigmas[:, col],
                                            np.asarray(own, dtype=float)[g.rows])
        scan = PemReferenceScan(kind=ref.kind, readings=g.pem.readings, sigmas=sigmas,
                                settings=g.pem.settings, amplitude_rad=g.pem.amplitude_rad,
                                angle_deg=ref.angle_deg,
                                retardance=math.radians(ref.retardance_deg))
    else:
        scan = ReferenceScan(kind=ref.kind, intensities=g.intensity, sigmas=g.sigma,
                             psg_retarder_deg=g.psg_retarder_deg,
                             psa_retarder_deg=g.psa_retarder_deg, angle_deg=ref.angle_deg,
                             retardance=math.radians(ref.retardance_deg))
    bench = str(prun.run.profile().get("bench", {}).get("name", ""))
    nominal = {"psa_retardance": math.radians(prun.retardance_deg("psa", g.wavelength_nm)),
               "psg_extinction": prun.extinction("psg"),
               "psa_extinction": prun.extinction("psa")}
    if g.pem is None:  # a PEM's source arm has a modulator, no retarder
        nominal["psg_retardance"] = math.radians(prun.retardance_deg("psg", g.wavelength_nm))
    return scan, nominal, bench


def calibrate_from_runs(refs: Sequence[ReferenceRun], *, bench: str | None = None
                        ) -> PolarimeterCalibration:
    """Fit the calibration to the reference runs (module docstring).

    Raises
    ------
    ValueError
        No air run, runs of different benches, PEM and DRR runs mixed, or a run that is
        not a one-position polarimetric scan.
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
    pem = [s for s in scans if isinstance(s, PemReferenceScan)]
    drr_scans = [s for s in scans if isinstance(s, ReferenceScan)]
    if pem and drr_scans:
        raise ValueError("the reference runs mix PEM and dual-rotating-retarder scans")
    nominal = trains[-1]
    drr = (calibrate_pem(pem, analyser_retardance=nominal["psa_retardance"],
                         psg_extinction=nominal["psg_extinction"],
                         psa_extinction=nominal["psa_extinction"]) if pem
           else calibrate_drr(drr_scans, **nominal))
    air = next(k for k, r in enumerate(refs) if r.kind == "air")
    ok, why = quality(drr)
    return PolarimeterCalibration(
        drr=drr, bench=bench or benches.pop(), source_scale_w=float(drr.sample_params[air][0]),
        date=now(), valid=ok, quality=why,
        references=tuple({"kind": r.kind, "run": str(Path(r.path).resolve()),
                          "angle_deg": r.angle_deg,
                          **({"retardance_deg": r.retardance_deg} if r.kind == "retarder"
                             else {})} for r in refs))
