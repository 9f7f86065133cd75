"""Run files for scripts: :func:`open_run`, labelled arrays, and the analyses.

``to_xarray()`` of a BRDF run is its *reduced* BRDF, one value per measured direction
with its uncertainty budget, through the same reduction as ``scatterlab fit``
(:func:`instrument.pipelines.brdf.reduce.reduce_run`; a spectral run per wavelength,
:func:`instrument.pipelines.brdf.spectral.reduce_spectral`). Every other run, and a BRDF
run with ``reduced=False``, gives its stored point table as recorded.

Conventions (ADR 0012): angles in degrees, θ from the sample normal, φ in the sample
plane; θr is the polar angle (not the in-plane signed angle of plan files). ``brdf`` is f
in 1/sr (f·cos θr when the reduction was cosine corrected, said in its attributes).
Uncertainties are standard uncertainties: ``u_brdf`` the independent part a fit weights
with, ``u_total`` with the common scale and the correlated terms added; ``u_scale_rel``
(an attribute) is the relative uncertainty common to every point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from instrument.run.runfile import RunData, check_run_file, read_events, read_run

if TYPE_CHECKING:
    import pandas
    import xarray

    from instrument.pipelines.brdf.pipeline import FitRun

__all__ = ["Run", "fit", "locate", "open_run", "reconstruct", "spheres"]

#: Plan kinds whose ``to_xarray()`` is the reduced BRDF.
BRDF_KINDS = ("brdf_in_plane", "brdf_hemisphere")
INSTALL_HINT = ("labelled arrays need xarray and pandas: "
                "pip install 'scatterlab[scripting]'")


def open_run(path: str | Path) -> Run:
    """A run file, checked and read (its tables; frames stay on disk).

    Raises
    ------
    RunFileError
        The file is missing, not a run file, or damaged (with what to do about it).
    """
    check_run_file(path)
    return Run(Path(path), read_run(path))


@dataclass(frozen=True)
class Run:
    """A run file opened for analysis. ``data`` holds every stored table
    (:class:`~instrument.run.runfile.RunData`)."""

    path: Path
    data: RunData

    @property
    def run_id(self) -> str:
        return self.data.run_id

    @property
    def kind(self) -> str:
        return self.data.plan_kind

    @property
    def status(self) -> str:
        return self.data.status

    @property
    def n_points(self) -> int:
        return self.data.n_points

    def events(self) -> list[dict[str, Any]]:
        """The run's event log (faults, pauses, homes, resumes), oldest first."""
        return read_events(self.path)

    # ---------------------------------------------------------------- arrays
    def to_xarray(self, *, reduced: bool | None = None, **reduction: Any) -> xarray.Dataset:
        """The run as an :class:`xarray.Dataset` along the dimension ``point`` (its values:
        each point's index in the run, so ``ds.sel(point=12)`` is point 12 of the file).

        ``reduced`` (default: yes for a BRDF run): the reduced BRDF with its
        uncertainties; ``reduction`` keywords are
        :class:`~instrument.pipelines.brdf.reduce.ReductionOptions` fields (a spectral
        run: :class:`~instrument.pipelines.brdf.spectral.SpectralOptions` fields).
        Otherwise the stored point table (signal, exposure, detector readings, read-back
        positions).
        """
        xr = _xarray()
        if reduced is None:
            reduced = self.kind in BRDF_KINDS
        if not reduced:
            if reduction:
                raise TypeError(f"reduction options {sorted(reduction)} need reduced=True")
            return _raw_dataset(xr, self.data)
        if self.kind not in BRDF_KINDS:
            raise ValueError(f"{self.path.name} is a {self.kind} run; only BRDF runs "
                             f"({', '.join(BRDF_KINDS)}) have a reduced BRDF: "
                             "use to_xarray(reduced=False)")
        return _reduced_dataset(xr, self.data, reduction)

    def to_pandas(self, **kwargs: Any) -> pandas.DataFrame:
        """:meth:`to_xarray` as a table, one row per point; units in ``df.attrs``."""
        ds = self.to_xarray(**kwargs)
        df = ds.to_dataframe()
        df.attrs = {**ds.attrs, "units": {k: ds[k].attrs.get("units", "")
                                          for k in list(ds.data_vars) + list(ds.coords)}}
        return df

    # -------------------------------------------------------------- analyses
    def fit(self, models: Any = None, **kwargs: Any) -> FitRun:
        """:func:`fit` of this run."""
        return fit(self.path, models, **kwargs)

    def reconstruct(self, **kwargs: Any) -> Any:
        """:func:`reconstruct` of this run."""
        return reconstruct(self.path, **kwargs)

    def locate(self, **kwargs: Any) -> Any:
        """:func:`locate` of this run."""
        return locate(self.path, **kwargs)

    def spheres(self, **kwargs: Any) -> Any:
        """:func:`spheres` of this run."""
        return spheres(self.path, **kwargs)

    def __repr__(self) -> str:
        return (f"<Run {self.run_id}: {self.kind}, {self.status}, "
                f"{self.n_points} points, sample {self.data.sample_name!r}>")


# ------------------------------------------------------------------ analyses
def fit(path: str | Path, models: Any = None, *, criterion: str = "bic",
        cross_validation: bool = True, bootstrap: int = 0, report: bool = True,
        write: bool = True, report_dir: str | Path | None = None,
        **reduction: Any) -> FitRun:
    """Reduce, fit and select models, as ``scatterlab fit`` does (same report and results
    file, unless ``report``/``write`` are off). ``models``: names (default: the CLI's
    candidates); ``reduction``: :class:`~instrument.pipelines.brdf.reduce.ReductionOptions`
    fields. Returns the run, its reduction and the analysis (``.result.chosen``,
    ``.result.chosen_fit.params``, ``.result.verdict``)."""
    from instrument.pipelines.brdf.analyse import DEFAULT_MODELS
    from instrument.pipelines.brdf.pipeline import fit_run
    from instrument.pipelines.brdf.reduce import ReductionOptions

    return fit_run(path, ReductionOptions(**reduction) if reduction else None,
                   tuple(models) if models is not None else DEFAULT_MODELS,
                   criterion=criterion, run_cv=cross_validation, n_bootstrap=bootstrap,
                   report_dir=report_dir, report=report, write=write)


def reconstruct(path: str | Path, **options: Any) -> Any:
    """The hidden object's light field from a light-field run, as ``scatterlab
    reconstruct`` (:func:`instrument.pipelines.lightfield.reconstruct.reconstruct_run`)."""
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run

    return reconstruct_run(path, **options)


def locate(path: str | Path, **options: Any) -> Any:
    """The hidden objects of a light-field run, each with its significance, as
    ``scatterlab locate`` (:func:`instrument.pipelines.lightfield.locate.locate_run`)."""
    from instrument.pipelines.lightfield.locate import locate_run

    return locate_run(path, **options)


def spheres(path: str | Path, **options: Any) -> Any:
    """Lighting and BRDF of a sphere capture, as ``scatterlab spheres``; returns
    ``(capture, analysis)`` (:func:`instrument.pipelines.spheres.pipeline.analyse_run`)."""
    from instrument.pipelines.spheres.pipeline import analyse_run

    return analyse_run(path, **options)


# ------------------------------------------------------------------- xarray
def _xarray() -> Any:
    try:
        import xarray
    except ImportError as err:
        raise ImportError(INSTALL_HINT) from err
    return xarray


def _var(values: Any, units: str, description: str) -> tuple[str, Any, dict[str, str]]:
    return ("point", np.asarray(values), {"units": units, "long_name": description})


ANGLE_DESCRIPTIONS = {"theta_i": "incidence polar angle", "phi_i": "incidence azimuth",
                      "theta_r": "scattering polar angle", "phi_r": "scattering azimuth"}


def _raw_dataset(xr: Any, run: RunData) -> xarray.Dataset:
    from instrument.run.layout import UNITS

    coords = {name: _var(getattr(run, name), "deg", text)
              for name, text in ANGLE_DESCRIPTIONS.items()}
    coords["point"] = _var(run.index, "", "point index in the plan's order")
    coords["label"] = _var(run.label.astype(str), "", "what the point measured")
    data = {
        "signal": _var(run.signal, UNITS["signal"], "detected signal rate"),
        "power_w": _var(run.power_w, UNITS["power_w"], "power meter reading"),
        "exposure_us": _var(run.exposure_us, UNITS["exposure_us"], "camera exposure"),
        "n_frames": _var(run.n_frames, "", "frames stored for the point"),
        "point_status": _var(run.point_status, "", "0 measured, 1 skipped, 2 frames lost"),
    }
    for k, role in enumerate(run.axes):
        data[f"position_{role}"] = _var(run.positions[:, k],
                                        "mm" if role == "camera_z" else "deg",
                                        f"read-back position of {role}")
    for name, values in run.detectors.items():
        if values is not None:
            data[name] = _var(values, UNITS.get(name, ""), name.replace("_", " "))
    return cast("xarray.Dataset",
                xr.Dataset(data, coords=coords, attrs=_run_attrs(run, reduced=False)))


def _reduced_dataset(xr: Any, run: RunData, reduction: dict[str, Any]) -> xarray.Dataset:
    from instrument.pipelines.brdf.spectral import has_wavelength_axis

    if has_wavelength_axis(run):
        from instrument.pipelines.brdf.spectral import SpectralOptions, reduce_spectral

        _, groups = reduce_spectral(run, SpectralOptions(**reduction))
        parts = [(red, g.wavelength_nm) for g, red in groups]
    else:
        from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run

        parts = [(reduce_run(run.path, ReductionOptions(**reduction)), None)]
    first = parts[0][0].points
    unit = "1/sr" + (" (f cos θr)" if first.cosine_corrected else "")

    def cat(get: Callable[..., Any]) -> np.ndarray:  # get(reduction)
        return np.concatenate([np.asarray(get(red)) for red, _ in parts])

    coords = {name: _var(np.degrees(cat(lambda r, n=name: getattr(r.points, n))), "deg", text)
              for name, text in ANGLE_DESCRIPTIONS.items()}
    coords["point"] = _var(cat(lambda r: r.point_index if r.point_index.size else r.rows),
                           "", "point index in the run")
    if any(len(red.sources) > 1 for red, _ in parts):  # a two-pass lobe run
        coords["run"] = _var(cat(lambda r: np.asarray(r.sources, dtype=str)[r.source]), "",
                             "the run the point was measured in (first or second pass)")
    if any(lam is not None for _, lam in parts):
        coords["wavelength_nm"] = _var(
            np.concatenate([np.full(red.points.n, lam) for red, lam in parts]), "nm",
            "centre wavelength of the filter")
    data = {
        "brdf": _var(cat(lambda r: r.points.brdf), unit, "BRDF"),
        "u_brdf": _var(cat(lambda r: r.points.u_point), unit,
                       "independent standard uncertainty (what a fit weights with)"),
        "u_stat": _var(cat(lambda r: r.points.u_stat), unit, "detector noise"),
        "u_angle": _var(cat(lambda r: r.points.u_angle), unit, "angular error"),
        "u_ref": _var(cat(lambda r: r.points.u_ref), unit, "reference per point"),
        "u_total": _var(cat(lambda r: r.points.u_total), unit,
                        "combined standard uncertainty (common scale included)"),
        "clipped": _var(cat(lambda r: ~r.points.valid), "",
                        "clipped reading: a lower bound, left out of fits"),
    }
    attrs = _run_attrs(run, reduced=True)
    attrs.update(u_scale_rel=float(first.u_scale_rel), method=first.method,
                 cosine_corrected=int(first.cosine_corrected),
                 warnings="\n".join(dict.fromkeys(w for red, _ in parts
                                                  for w in red.warnings)))
    return cast("xarray.Dataset", xr.Dataset(data, coords=coords, attrs=attrs))


def _run_attrs(run: RunData, *, reduced: bool) -> dict[str, Any]:
    return {"run_id": run.run_id, "plan_kind": run.plan_kind, "plan_name": run.plan_name,
            "sample": run.sample_name, "status": run.status, "source": str(run.path),
            "content": "reduced BRDF" if reduced else "stored point table",
            "conventions": "angles in degrees from the sample normal (ADR 0012)"}
