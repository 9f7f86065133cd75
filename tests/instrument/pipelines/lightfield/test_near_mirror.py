"""A 3 mm disc in front of a near-mirror wall (specular width 0.01°), located at n_theta 1024.

At 1024 angles on the 1024-pixel sensor the transverse blur is ≈ 1.5 mm, half the disc:
the disc is an object larger than the blur.  It used to come back as two objects 1.7 mm
apart, both "depth resolved", after `reconstruct`'s note had asked for more angles that
the camera cannot give.  Through the CLI, as a user runs it, with `locate`'s default search:
the disc must come back as one object (extended, with a size that holds its 3 mm), and the
note must not ask for more angles; at n_theta 256 (the cheap twin, in the default run) as
one object too.  The exposure is lowered from the example's so that no frame saturates (the
plan's auto-exposure is a separate matter).
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.cli import main
from instrument.run.paths import results_path

ROOT = Path(__file__).parents[4]
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-lightfield.toml"
EXAMPLE = ROOT / "examples" / "lightfield_scan.toml"
GROUP = "entry/analysis/lightfield"
DISC = (-8.0, -200.0, 1.5)  # y, z, radius (mm)


def _near_mirror_bench(tmp_path: Path) -> Path:
    text = PROFILE.read_text()
    text = text.replace('material = "brushed_metal"',
                        'brdf = { specular_reflectance = 0.6, specular_width_deg = 0.01, '
                        'diffuse_reflectance = 0.08, name = "near_mirror" }')
    bar = next(line for line in text.splitlines() if 'kind = "bar"' in line)
    text = text.replace(bar + "\n", "")
    assert "near_mirror" in text and 'kind = "bar"' not in text
    path = tmp_path / "near_mirror.toml"
    path.write_text(text)
    return path


def _scan(tmp_path: Path) -> Path:
    """The near-mirror scan at 100 µs (no frame saturated): the run file."""
    plan = tmp_path / "plan.toml"
    plan.write_text(EXAMPLE.read_text().replace("exposure_us = 5000", "exposure_us = 100"))
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--bench", str(_near_mirror_bench(tmp_path)), "--out",
                 str(out), "--no-fsync", "--quiet"]) == 0
    (run,) = sorted(out.glob("*.h5"))
    with h5py.File(run, "r") as f:
        assert not f["entry/data/frame_saturated"][()].any()
    return run


def _located(run: Path, n_theta: int, capsys) -> tuple[np.ndarray, ...]:
    """``locate`` with its default search (the wall points ± 60 mm, 0.5 mm across;
    −400 … −60 mm, 1 mm deep), as a user runs it: positions, blurs across, flags, extents
    and depth intervals of the objects."""
    capsys.readouterr()
    assert main(["locate", str(run), "--n-theta", str(n_theta), "--no-figures"]) in (0, 1)
    assert "raise n_theta" not in capsys.readouterr().out
    with h5py.File(results_path(run, "lightfield"), "r") as f:
        loc = f[f"{GROUP}/localisation"]
        quality = [q.decode() if isinstance(q, bytes) else q for q in loc["quality"][()]]
        return (loc["positions_mm"][()].reshape(-1, 2), loc["transverse_mm"][()],
                np.asarray(quality), loc["extent_mm"][()].reshape(-1, 2),
                loc["depth_interval_mm"][()].reshape(-1, 2))


def _one_object_over_the_disc(pos, dy, quality, interval) -> int:
    """Everything reported over the disc (within its radius and two blurs across) is one
    object whose depth interval holds the disc, and nothing else is "resolved"; its
    index."""
    y0, z0, radius = DISC
    over = np.nonzero(np.abs(pos[:, 0] - y0) < radius + 2 * dy)[0]
    assert over.size == 1, (pos, quality)
    (k,) = over
    assert abs(pos[k, 0] - y0) < radius + dy[k]
    assert interval[k, 0] <= z0 <= interval[k, 1]
    assert all(quality[j] != "resolved" for j in range(len(pos)) if j != k)
    return int(k)


@pytest.mark.slow
@pytest.mark.timeout(1800)  # ≈ 35 s CPU (scan, reconstruct twice, locate 29 s); wall time
# on a loaded box several times that
def test_a_disc_before_a_near_mirror_at_n_theta_1024_is_one_object(tmp_path, capsys):
    run = _scan(tmp_path)
    capsys.readouterr()
    assert main(["reconstruct", str(run), "--n-theta", "1024", "--no-figures"]) == 0
    text = capsys.readouterr().out
    # no remedy the camera cannot give: 1024 angles is its pixel limit
    assert "raise n_theta" not in text
    if "over-regularised" in text:
        assert "more angles cannot help" in text

    # the issue's case: the default search (≈ 29 s of CPU at 1024 angles since the models'
    # samples are laid out once, BENCHMARKS.md "locate at n_theta 1024 in about a minute")
    pos, dy, quality, extent, interval = _located(run, 1024, capsys)
    assert dy.size and np.all(dy < 2 * DISC[2])  # the disc is larger than the blur
    k = _one_object_over_the_disc(pos, dy, quality, interval)
    if quality[k] == "extended":
        # its size holds the disc's 3 mm within the blur
        assert abs(extent[k, 0] - 2 * DISC[2]) < dy[k] + 1e-9


@pytest.mark.timeout(900)  # ≈ 12 s CPU (scan, locate 7.6 s with its reconstruction)
def test_a_disc_before_a_near_mirror_at_n_theta_256_is_one_object(tmp_path, capsys):
    """The cheap twin: at 256 angles (p̂ 67, the wall's angular resolution the limit) the
    blur is 1.7 mm across, the disc still larger than it; it comes back as one object over
    the disc (its depth flagged unresolved: point sources leave 7.8× the noise), never as
    "resolved" parts."""
    pos, dy, quality, _, interval = _located(_scan(tmp_path), 256, capsys)
    _one_object_over_the_disc(pos, dy, quality, interval)
