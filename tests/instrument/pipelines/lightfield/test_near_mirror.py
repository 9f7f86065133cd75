"""A 3 mm disc in front of a near-mirror wall (specular width 0.01°), located at n_theta 1024.

At 1024 angles on the 1024-pixel sensor the transverse blur is ≈ 1.5 mm, half the disc:
the disc is an object larger than the blur.  It used to come back as two objects 1.7 mm
apart, both "depth resolved", after `reconstruct`'s note had asked for more angles that
the camera cannot give.  Through the CLI, as a user runs it: the disc must come back as one
object (extended, with a size that holds its 3 mm), and the note must not ask for more
angles.  The exposure is lowered from the example's so that no frame saturates (the
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


@pytest.mark.slow
@pytest.mark.timeout(1800)  # ≈ 80 s CPU; 600 s of wall time is too little on a loaded box
def test_a_disc_before_a_near_mirror_at_n_theta_1024_is_one_object(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(EXAMPLE.read_text().replace("exposure_us = 5000", "exposure_us = 100"))
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--bench", str(_near_mirror_bench(tmp_path)), "--out",
                 str(out), "--no-fsync", "--quiet"]) == 0
    (run,) = sorted(out.glob("*.h5"))
    with h5py.File(run, "r") as f:
        assert not f["entry/data/frame_saturated"][()].any()
    capsys.readouterr()

    assert main(["reconstruct", str(run), "--n-theta", "1024", "--no-figures"]) == 0
    text = capsys.readouterr().out
    # no remedy the camera cannot give: 1024 angles is its pixel limit
    assert "raise n_theta" not in text
    if "over-regularised" in text:
        assert "more angles cannot help" in text

    # the search around the disc (at 1024 angles the default 120 × 340 mm search costs
    # ≈ 150 s of CPU, BENCHMARKS.md "locate at n_theta 1024"; the narrower one less)
    assert main(["locate", str(run), "--n-theta", "1024", "--no-figures", "--y-range", "-40",
                 "25", "--z-range", "-320", "-100"]) in (0, 1)
    text = capsys.readouterr().out
    assert "raise n_theta" not in text
    with h5py.File(results_path(run, "lightfield"), "r") as f:
        loc = f[f"{GROUP}/localisation"]
        pos = loc["positions_mm"][()].reshape(-1, 2)
        dy = loc["transverse_mm"][()]
        quality = [q.decode() if isinstance(q, bytes) else q for q in loc["quality"][()]]
        extent = loc["extent_mm"][()].reshape(-1, 2)
        interval = loc["depth_interval_mm"][()].reshape(-1, 2)
    y0, z0, radius = DISC
    assert dy.size and np.all(dy < 2 * radius)  # the disc is larger than the blur
    # everything reported over the disc (within its radius and two blurs across) is one
    # object: never two "resolved" points
    over = np.nonzero(np.abs(pos[:, 0] - y0) < radius + 2 * dy)[0]
    assert over.size == 1, (pos, quality)
    (k,) = over
    assert abs(pos[k, 0] - y0) < radius + dy[k]
    assert interval[k, 0] <= z0 <= interval[k, 1]
    if quality[k] == "extended":
        # its size holds the disc's 3 mm within the blur
        assert abs(extent[k, 0] - 2 * radius) < dy[k] + 1e-9
    # nothing else is reported as a resolved object
    assert all(quality[j] != "resolved" for j in range(len(pos)) if j != k)
