"""A sphere-capture run file → SH analysis → stored results and the relighting figure.

:func:`analyse_run` is what ``scatterlab spheres`` does, callable from scripts, the GUI and
batch analyses. Its results go to ``DIR/RUN/spheres/results.h5`` next to the run file
``DIR/RUN.h5`` (ADR 0013); the run file is only read, unless ``into_run`` asks for the
results in it as well.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from instrument.pipelines.spheres.analyse import SphereAnalysis, analyse_capture
from instrument.pipelines.spheres.capture import SphereCapture, read_capture
from instrument.pipelines.spheres.figures import relighting_figure
from instrument.pipelines.spheres.results import write_sphere_analysis, write_sphere_results
from instrument.run.runfile import check_run_file, read_run

__all__ = ["analyse_run", "sphere_options"]


def sphere_options(**options: Any) -> dict[str, Any]:
    """The options of :func:`analyse_run` that change its results, as recorded in the
    results file (and compared by :func:`instrument.run.results.already_done`)."""
    return dict(sorted(options.items()))


def analyse_run(path: str | Path, *, write: bool = True, figure: str | Path | None = None,
                into_run: bool = False, out_dir: str | Path | None = None,
                **options: Any) -> tuple[SphereCapture, SphereAnalysis]:
    """Read, analyse and (by default) store a sphere capture; optionally draw the figure.

    ``write``: the results file (in ``out_dir``, default ``DIR/RUN/spheres/``);
    ``into_run``: the run file's ``/entry/analysis`` too. ``options`` go to
    :func:`analyse_capture`. Raises :class:`~instrument.run.runfile.RunFileError` first
    when the file is not a readable sphere-capture run.
    """
    check_run_file(path, "spheres")
    capture = read_capture(path)
    result = analyse_capture(capture, **options)
    if write:
        write_sphere_results(path, capture, result, run_id=read_run(path).run_id,
                             options=sphere_options(**options), folder=out_dir)
    if into_run:
        write_sphere_analysis(path, capture, result)
    if figure is not None:
        Path(figure).parent.mkdir(parents=True, exist_ok=True)
        relighting_figure(capture, result, figure)
    return capture, result
