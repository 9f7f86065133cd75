"""Reconstruction of a light-field run: the hidden object's light field at the wall.

:func:`reconstruct_run` assembles the measured field (:mod:`.scan`) and runs
:func:`analysis.lightfield.reconstruct` (per scattering point, closed form of Sasaki's thesis
eqs. 2-32/33, Wiener filter from the pooled signal spectrum; ADR 0030) on the scattering
points whose curves lie inside the measured y range; results and figures as in
:mod:`~instrument.pipelines.lightfield.results` and
:mod:`~instrument.pipelines.lightfield.figures`.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from analysis.lightfield import (
    FlatlandBRDF,
    LightField2D,
    effective_p_max,
    reconstruct,
)
from instrument.pipelines.lightfield.figures import reconstruction_figures
from instrument.pipelines.lightfield.geometry import (
    LightFieldGeometry,
    brdf_from_run,
    geometry_from_run,
)
from instrument.pipelines.lightfield.results import ReconstructionResult, write_reconstruction
from instrument.pipelines.lightfield.scan import assemble, read_scan
from instrument.run.runfile import check_run_file, read_summary

__all__ = ["NOISE_DISAGREEMENT_FACTOR", "reconstruct_options", "reconstruct_run",
           "scattering_points"]


def scattering_points(lf: LightField2D, d2_mm: float) -> NDArray[np.float64]:
    """Wall points whose whole curve ``c + d2 tan θ``, θ ∈ [a, b], lies in the measured y
    range, on the measurement grid's step."""
    a, b = lf.domain_rad
    lo = lf.y_mm[0] - d2_mm * math.tan(a)
    hi = lf.y_mm[-1] - d2_mm * math.tan(b)
    if hi <= lo:
        raise ValueError("the scan is too short for any complete curve: widen the camera_z "
                         "range or narrow the angle domain")
    n = math.floor((hi - lo) / lf.dy_mm + 1e-9) + 1
    return cast(np.ndarray, lo + lf.dy_mm * np.arange(n))  # numpy's stubs: Any


def reconstruct_run(
    path: str | Path,
    *,
    geometry: LightFieldGeometry | None = None,
    brdf: FlatlandBRDF | None = None,
    domain_rad: tuple[float, float] | None = None,
    n_theta: int = 128,
    method: str = "wiener",
    write: bool = True,
    figures_dir: str | Path | None = None,
    out_dir: str | Path | None = None,
    into_run: bool = False,
) -> ReconstructionResult:
    """Assemble L_meas from the run, reconstruct the object light field, store the result.

    ``geometry``/``brdf`` default to the emulated bench's own (:func:`geometry_from_run`,
    :func:`brdf_from_run`).  With ``write`` the measured field and the reconstruction go
    into ``/entry/analysis/lightfield`` of the results file (in ``out_dir``, default
    ``DIR/RUN/lightfield/``; ADR 0013), with ``into_run`` into the run file as well; with
    ``figures_dir`` the PNG figures too. Raises
    :class:`~instrument.run.runfile.RunFileError` first when the file is not a readable
    light-field run.
    """
    check_run_file(path, "reconstruct")
    recorded = reconstruct_options(geometry=geometry, brdf=brdf, domain_rad=domain_rad,
                                   n_theta=n_theta, method=method)
    geometry = geometry or geometry_from_run(path)
    brdf = brdf or brdf_from_run(path)
    scan = read_scan(path, geometry)
    measured = assemble(scan, d2_mm=geometry.d2_mm, domain_rad=domain_rad, n_theta=n_theta)
    lf = measured.field
    points = scattering_points(lf, geometry.d2_mm)
    # method: a str that reconstruct checks itself (ValueError), not narrowed to its Literal
    rec = reconstruct(lf, brdf, d2_mm=geometry.d2_mm, points_mm=points,
                      method=method)  # type: ignore[arg-type]
    p_hat = effective_p_max(rec.regularization.filter_factors, rec.orders)
    notes = scan.notes + _noise_disagreement(rec.diagnostics.noise.sigma_per_sample,
                                             measured.sigma_rows, n_theta,
                                             pixels_per_cell=float(np.min(measured.cell_pixels)),
                                             specular_width_rad=brdf.specular_width_rad,
                                             cell_rad=lf.dtheta_rad)
    result = ReconstructionResult(measured, rec, p_hat, geometry, brdf, notes)
    if write:
        write_reconstruction(path, result, run_id=read_summary(path).run_id,
                             options=recorded, folder=out_dir)
    if into_run:
        write_reconstruction(path, result, into_run=True)
    if figures_dir is not None:
        figs = reconstruction_figures(result, figures_dir)
        result = ReconstructionResult(measured, rec, p_hat, geometry, brdf, notes, tuple(figs))
    return result


def reconstruct_options(*, geometry: LightFieldGeometry | None = None,
                        brdf: FlatlandBRDF | None = None,
                        domain_rad: tuple[float, float] | None = None, n_theta: int = 128,
                        method: str = "wiener") -> dict[str, Any]:
    """The options of :func:`reconstruct_run` that change its result, as recorded in the
    results file (``None``: the bench's own geometry or wall)."""
    return {"geometry": None if geometry is None else geometry.as_dict(),
            "brdf": None if brdf is None else asdict(brdf),
            "domain_rad": None if domain_rad is None else list(domain_rad),
            "n_theta": n_theta, "method": method}


#: Tail-noise estimate over sensor-row prediction above which the tail holds signal.  The
#: two agree to ~10 % on a resolved scan (examples/lightfield_scan.toml: 2.08e-4 against
#: 2.25e-4 at the default 128 angles); a factor 3 is
#: far outside the scatter of either estimate, so it flags aliasing, not noise.
NOISE_DISAGREEMENT_FACTOR = 3.0


def _noise_disagreement(sigma_tail: float, sigma_rows: float, n_theta: int, *,
                        pixels_per_cell: float = np.inf, specular_width_rad: float = 0.0,
                        cell_rad: float = 0.0) -> tuple[str, ...]:
    """A note when the high-frequency tail is dominated by signal, not noise.

    The Wiener/GCV/discrepancy parameters use the tail estimate; if the angular grid is too
    coarse for the signal, the tail holds signal, the noise is overestimated and the
    reconstruction over-smoothed (or declared unrecoverable).  The remedy it names must be
    possible: an angle cell cannot be narrower than a camera pixel, so n_theta can grow only
    by ``pixels_per_cell`` (the fewest pixels in a cell); at that limit, and when the wall's
    specular lobe is narrower than one cell, the camera's angular sampling of the wall is
    the limit, and the note says so instead of asking for more angles.
    """
    if not (sigma_rows > 0 and sigma_tail > NOISE_DISAGREEMENT_FACTOR * sigma_rows):
        return ()
    head = (f"the noise estimated from the high-frequency tail ({sigma_tail:.3g}) is "
            f"{sigma_tail / sigma_rows:.0f}× the sensor-row prediction ({sigma_rows:.3g}): "
            f"the tail holds signal, so the reconstruction is over-regularised; ")
    n_max = int(n_theta * pixels_per_cell) if np.isfinite(pixels_per_cell) else None
    if n_max is not None and n_max < 2 * n_theta:
        lobe = (f"the wall's specular lobe ({np.degrees(specular_width_rad):.3g}°) is "
                f"narrower than one angle cell ({np.degrees(cell_rad):.3g}°) at the camera's "
                f"pixel limit, " if specular_width_rad < cell_rad else "")
        reach = ("already samples about one camera pixel per angle" if n_max >= n_theta
                 else "asks for angle cells narrower than a camera pixel")
        return (head + f"n_theta {n_theta} {reach} (at most {n_max}): {lobe}the camera's "
                f"angular resolution of the wall is the limit, not n_theta — more angles "
                f"cannot help; trust positions, not fine angular detail",)
    hint = f" (at most {n_max}, one camera pixel per angle)" if n_max is not None else ""
    return (head + f"raise n_theta (now {n_theta}{hint}) until the two agree",)
