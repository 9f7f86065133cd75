"""A sphere-capture run file → SH analysis → stored results and the relighting figure.

:func:`analyse_run` is what ``scatterlab spheres`` does, callable from scripts and the GUI.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from instrument.pipelines.spheres.analyse import SphereAnalysis, analyse_capture
from instrument.pipelines.spheres.capture import SphereCapture, read_capture
from instrument.pipelines.spheres.figures import relighting_figure
from instrument.pipelines.spheres.results import write_sphere_analysis

__all__ = ["analyse_run"]


def analyse_run(path: str | Path, *, write: bool = True, figure: str | Path | None = None,
                **options: Any) -> tuple[SphereCapture, SphereAnalysis]:
    """Read, analyse and (by default) write back a sphere capture; optionally draw the figure.

    ``options`` go to :func:`analyse_capture`.
    """
    capture = read_capture(path)
    result = analyse_capture(capture, **options)
    if write:
        write_sphere_analysis(path, capture, result)
    if figure is not None:
        relighting_figure(capture, result, figure)
    return capture, result
