"""The polarimeter calibration as a file: written by ``scatterlab calibrate polarimeter``,
looked up by ``scatterlab fit``.

A calibration is the fit of the dual rotating retarder's five hidden parameters
(:func:`analysis.polarimetry.calibration.calibrate_drr`: retarder offsets, retardances,
analyser polariser axis) to reference scans, with their covariance and the fit's χ²; on
a PEM polarimeter the five of :func:`analysis.polarimetry.pem_calibration.calibrate_pem`
(modulator amplitude and axis, analyser retarder axis and retardance, analyser polariser
axis; ADR 0113). The file's ``mode`` (``"drr"``, or ``"pem"``; files without it are a
DRR's) says which, and a run is reduced only with a calibration of its own mode.
It is stored as JSON (``polarimeter-<bench>-<time>.json``) in a ``calibrations/``
folder beside the runs, with its provenance: the bench, the reference runs, the date and
the software version. ``fit`` uses the calibration it is given (``--calibration FILE``),
else the newest *valid* one for the run's bench in ``calibrations/`` next to the run file.

Validity (the quality gate): the fit's χ²/dof within 5 standard deviations of 1
(``|χ²/dof − 1| ≤ 5·√(2/dof)``) and finite σ for every parameter; an invalid calibration
is kept on disk, with the reason, but never picked up automatically.
"""

from __future__ import annotations

import datetime
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.polarimetry.calibration import INSTRUMENT_PARAMS, DrrCalibration
from analysis.polarimetry.pem_calibration import PEM_PARAMS, PemCalibration
from instrument.version import software_version

__all__ = ["CALIBRATION_KIND", "CalibrationError", "PolarimeterCalibration",
           "calibration_folder", "find_calibration", "load_calibration",
           "save_calibration"]

CALIBRATION_KIND = "polarimeter_calibration"
FOLDER = "calibrations"


class CalibrationError(ValueError):
    """A calibration file that cannot be used (named, with what is wrong)."""


@dataclass(frozen=True)
class PolarimeterCalibration:
    """A polarimeter calibration and its provenance.

    ``source_scale_w`` is the intensity (W) of the unit unpolarised source that the
    instrument matrix assumes, measured on the air scan: a reduced matrix divided by it
    is a transmittance. ``drr`` holds the fitted parameters: a
    :class:`~analysis.polarimetry.calibration.DrrCalibration` or, for a PEM polarimeter,
    a :class:`~analysis.polarimetry.pem_calibration.PemCalibration` (:attr:`mode`).
    """

    drr: DrrCalibration | PemCalibration
    bench: str
    source_scale_w: float
    date: str
    references: tuple[dict[str, Any], ...] = ()
    valid: bool = True
    quality: str = ""
    path: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def mode(self) -> str:
        """``"pem"`` for a PEM polarimeter's calibration, else ``"drr"``."""
        return "pem" if isinstance(self.drr, PemCalibration) else "drr"

    def to_dict(self) -> dict[str, Any]:
        d = self.drr
        return {
            "kind": CALIBRATION_KIND, "mode": self.mode, "bench": self.bench,
            "date": self.date, "software_version": software_version(),
            "param_names": list(PEM_PARAMS if self.mode == "pem" else INSTRUMENT_PARAMS),
            "params": [float(v) for v in d.params],
            "sigma": [float(v) for v in d.sigma],
            "covariance": np.asarray(d.cov, dtype=float).tolist(),
            "chi2": d.chi2, "dof": d.dof,
            "psg_extinction": d.psg_extinction, "psa_extinction": d.psa_extinction,
            "sample_params": [list(p) for p in d.sample_params],
            "source_scale_w": self.source_scale_w,
            "references": list(self.references),
            "valid": self.valid, "quality": self.quality, **self.extra,
        }

    def describe(self) -> str:
        """One line: the fitted parameters with σ (angles in degrees)."""
        p, s = self.drr.params, self.drr.sigma
        if self.mode == "pem":
            return (f"PEM amplitude × {p[0]:.4f} ± {s[0]:.4f}, PEM axis {p[1]:+.3f} ± "
                    f"{s[1]:.3f}°, analyser retarder {p[2]:+.3f} ± {s[2]:.3f}° "
                    f"({math.degrees(p[3]):.2f} ± {math.degrees(s[3]):.2f}°), analyser "
                    f"polariser {p[4]:+.3f} ± {s[4]:.3f}°")
        return (f"retarder offsets {p[0]:+.3f} ± {s[0]:.3f}° / {p[1]:+.3f} ± {s[1]:.3f}°, "
                f"retardances {math.degrees(p[2]):.2f} ± {math.degrees(s[2]):.2f}° / "
                f"{math.degrees(p[3]):.2f} ± {math.degrees(s[3]):.2f}°, analyser polariser "
                f"{p[4]:+.3f} ± {s[4]:.3f}°")


def quality(drr: DrrCalibration | PemCalibration) -> tuple[bool, str]:
    """The gate of the module docstring: (valid, the reason in words)."""
    if drr.dof <= 0:
        return False, "no degrees of freedom left: add steps or reference scans"
    red = drr.chi2 / drr.dof
    limit = 5.0 * math.sqrt(2.0 / drr.dof)
    if not np.all(np.isfinite(drr.sigma)):
        return False, "a parameter is not determined (infinite σ): add reference scans"
    if abs(red - 1.0) > limit:
        return False, (f"χ²/dof = {red:.3g} is more than 5σ ({limit:.2g}) from 1: the "
                       "references do not fit the polarimeter model")
    return True, f"χ²/dof = {red:.3g} ({drr.dof} dof)"


def calibration_folder(run_folder: str | Path) -> Path:
    """``DIR/calibrations/`` for runs in ``DIR``."""
    return Path(run_folder) / FOLDER


def save_calibration(cal: PolarimeterCalibration, folder: str | Path,
                     name: str | None = None) -> Path:
    """Write the calibration JSON into ``folder`` (atomically); returns its path."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    stamp = cal.date.replace(":", "").replace("-", "")
    path = out / (name or f"polarimeter-{cal.bench}-{stamp}.json")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(cal.to_dict(), indent=1), encoding="utf-8")
    tmp.replace(path)
    return path


def load_calibration(path: str | Path) -> PolarimeterCalibration:
    """Read a calibration JSON.

    Raises
    ------
    CalibrationError
        Not a polarimeter calibration, or a field missing or malformed (named).
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise CalibrationError(f"{p}: cannot read the polarimeter calibration ({err})"
                               ) from None
    if not isinstance(data, dict) or data.get("kind") != CALIBRATION_KIND:
        raise CalibrationError(f"{p} is not a polarimeter calibration (kind "
                               f"{CALIBRATION_KIND!r}); write one with `scatterlab "
                               "calibrate polarimeter`")
    try:
        params = np.asarray(data["params"], dtype=float)
        cov = np.asarray(data["covariance"], dtype=float)
        if params.shape != (5,) or cov.shape != (5, 5):
            raise ValueError("params must hold 5 numbers and covariance 5×5")
        mode = data.get("mode", "drr")  # files before PEM calibrations are a DRR's
        if mode not in ("drr", "pem"):
            raise ValueError(f"mode must be 'drr' or 'pem', got {mode!r}")
        kind = PemCalibration if mode == "pem" else DrrCalibration
        drr = kind(params=params, cov=cov,
                   sample_params=tuple(tuple(float(v) for v in sp)
                                       for sp in data.get("sample_params", [])),
                   chi2=float(data["chi2"]), dof=int(data["dof"]),
                   # files written before the field modelled ideal polarisers
                   psg_extinction=float(data.get("psg_extinction", 0.0)),
                   psa_extinction=float(data.get("psa_extinction", 0.0)))
        return PolarimeterCalibration(
            drr=drr, bench=str(data["bench"]), source_scale_w=float(data["source_scale_w"]),
            date=str(data["date"]), references=tuple(data.get("references", [])),
            valid=bool(data.get("valid", False)), quality=str(data.get("quality", "")),
            path=p)
    except (KeyError, TypeError, ValueError) as err:
        raise CalibrationError(f"{p}: malformed polarimeter calibration ({err})") from None


def find_calibration(run_path: str | Path, bench: str, mode: str = "drr"
                     ) -> PolarimeterCalibration | None:
    """The newest valid calibration of ``bench`` and of the run's polarimeter ``mode``
    (``"drr"`` or ``"pem"``) in ``calibrations/`` next to the run."""
    folder = calibration_folder(Path(run_path).resolve().parent)
    best: PolarimeterCalibration | None = None
    for f in sorted(folder.glob("polarimeter-*.json")):
        try:
            cal = load_calibration(f)
        except CalibrationError:
            continue  # a damaged file is not a candidate; naming it with --calibration says why
        if (cal.bench == bench and cal.mode == mode and cal.valid
                and (best is None or cal.date > best.date)):
            best = cal
    return best


def now() -> str:
    """The calibration's date: UTC, ISO 8601 to the second (sortable)."""
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
