"""Small simulated BRDF runs for the batch tests, made once per test module.

The frames are rendered by the simulated camera/scene/sensor code (tests/instrument/
sim_scan.py) on a coarse θr grid and written by the engine's own writer, so each run is a
real run file that ``scatterlab fit`` reduces and fits in a fraction of a second.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from tests.instrument.sim_scan import SAMPLES, ScanSetup, render, write_flat_run, write_run_file

#: θi = 20°, 40°, 60°; θr every 20° plus ±4° around specular: 39 points per run.
SETUP = ScanSetup(theta_r_step=20.0)


def make_brdf_runs(folder: Path, n: int) -> list[Path]:
    """``n`` runs in ``folder``: glossy and Oren–Nayar samples in turn, one sensor seed
    each, named ``run-00.h5`` … with run ids to match."""
    folder.mkdir(parents=True, exist_ok=True)
    rendered = [render(SETUP, SAMPLES[1]), render(SETUP, SAMPLES[2])]
    return [write_run_file(rendered[k % 2], 10 + k, folder / f"run-{k:02d}.h5",
                           run_id=f"run-{k:02d}") for k in range(n)]


def make_flat_run(folder: Path) -> Path:
    """A ``flat_field`` calibration run (not a run that ``fit`` analyses)."""
    return write_flat_run(SETUP, 10, folder / "flat.h5", n_frames=2)


def fresh_copy(src: Path, dst: Path) -> Path:
    """A copy of the runs folder ``src`` (run files only) for a test that writes results."""
    dst.mkdir(parents=True, exist_ok=True)
    for p in src.glob("*.h5"):
        shutil.copy2(p, dst / p.name)
    return dst


def parse_cli(argv: list[str]):
    """The arguments as ``scatterlab`` parses them (the named subcommand in full)."""
    from instrument.cli import build_parser

    return build_parser(argv).parse_args(argv)
