"""A release as a lab gets it (ADR 0094): a wheel built from a git tag installs into a fresh
virtual environment and runs the README's main job with no source tree in sight.

The repository's committed state is cloned into a temporary folder (so untracked files
and an installed egg-info cannot leak in), its tags are replaced by one test tag, and
``python -m build`` makes the sdist and, from that sdist, the wheel, without build
isolation (the tools are the dev extra's; nothing is downloaded). The wheel is installed
with ``--no-deps`` into a new venv whose heavy dependencies (NumPy, h5py, OpenCV, Qt...)
are this environment's site-packages, added by a ``.pth`` line: a path added that way is
not a site directory, so the editable install of the checkout is not seen, and the test
asserts that ``instrument`` is imported from the new venv. The main job then runs from a
temporary folder outside the tree, with the examples written out by ``scatterlab examples
copy`` and the bench profile resolved by name from the package.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import h5py
import pytest

ROOT = Path(__file__).resolve().parents[1]
TAG_VERSION = "1.2.3"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.timeout(1800),  # a build, an install and a scan on a shared machine
    pytest.mark.skipif(shutil.which("git") is None, reason="git is needed to clone and tag"),
]


def _run(argv: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
    proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=1500, **kw)
    assert proc.returncode == 0, (
        f"{argv} exited {proc.returncode}\n--- stdout\n{proc.stdout[-4000:]}"
        f"\n--- stderr\n{proc.stderr[-4000:]}")
    return proc


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    """The sdist and wheel built from a clone of the committed tree, tagged v1.2.3."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the version comes from a git tag")
    work = tmp_path_factory.mktemp("release")
    src = work / "src"
    _run(["git", "clone", "--quiet", str(ROOT), str(src)], cwd=work)
    tags = _run(["git", "tag", "--list"], cwd=src).stdout.split()
    if tags:
        _run(["git", "tag", "--delete", *tags], cwd=src)
    _run(["git", "-c", "user.name=release test", "-c", "user.email=release@test",
          "tag", "-a", f"v{TAG_VERSION}", "-m", "release test"], cwd=src)
    dist = work / "dist"
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(src)],
         cwd=work)
    (wheel,) = dist.glob("*.whl")
    (sdist,) = dist.glob("*.tar.gz")
    return {"work": work, "wheel": wheel, "sdist": sdist}


def test_the_tag_is_the_version_of_both_files(built) -> None:
    assert built["wheel"].name == f"scatterlab-{TAG_VERSION}-py3-none-any.whl"
    assert built["sdist"].name == f"scatterlab-{TAG_VERSION}.tar.gz"


def test_the_wheel_carries_profiles_and_examples_and_no_tests(built) -> None:
    names = set(zipfile.ZipFile(built["wheel"]).namelist())
    for name in ("instrument/bench/profiles/sim.toml", "instrument/_examples/brdf_inplane.toml",
                 "instrument/_examples/camera_calibration_sim.json",
                 "instrument/_examples/notebooks/adaptive_lobe.ipynb",
                 "instrument/server/dashboard/static/index.html"):
        assert name in names, name
    assert not any(n.startswith(("tests/", "benchmarks/", "docs/")) for n in names)
    with tarfile.open(built["sdist"]) as tar:
        members = {m.name.split("/", 1)[1] for m in tar.getmembers() if "/" in m.name}
    for name in ("setup.py", "pyproject.toml", "CHANGELOG.md", "examples/brdf_inplane.toml",
                 "instrument/bench/profiles/sim.toml", "PKG-INFO"):
        assert name in members, name


def test_the_installed_wheel_runs_the_main_job_outside_the_tree(built) -> None:
    work = built["work"]
    venv = work / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=work)
    py = venv / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=work).stdout.strip())
    # the dependencies from this environment (no download); not a site dir, so its .pth
    # files (the checkout's editable install among them) are not processed
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(py), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
          str(built["wheel"])], cwd=work)

    job = work / "job"  # outside the tree: nothing of the checkout is importable from here
    job.mkdir()
    where = _run([str(py), "-c", "import instrument, instrument.bench.profile as p; "
                  "print(instrument.__file__); print(' '.join(p.builtin_profiles()))"],
                 cwd=job).stdout.split("\n")
    assert Path(where[0]).is_relative_to(venv), where[0]
    assert "sim" in where[1].split() and "sim-spectral" in where[1].split()

    scatterlab = str(venv / "bin" / "scatterlab")
    assert _run([scatterlab, "--version"], cwd=job).stdout.strip() == \
        f"scatterlab {TAG_VERSION}"
    _run([scatterlab, "examples", "copy", "examples"], cwd=job)
    assert (job / "examples" / "brdf_inplane.toml").read_bytes() == \
        (ROOT / "examples" / "brdf_inplane.toml").read_bytes()
    out = _run([scatterlab, "run", "examples/brdf_inplane.toml", "--bench", "sim"],
               cwd=job).stdout
    (run_file,) = (job / "runs").glob("*.h5")
    assert run_file.name in out
    with h5py.File(run_file, "r") as f:
        entry = f["entry"]
        assert entry.attrs["software_version"] == f"scatterlab {TAG_VERSION}"
        assert entry.attrs["status"] == "finished"
        n_planned = int(entry.attrs["n_planned"])
        assert n_planned > 0
        assert len(entry["points"]["index"]) == n_planned
        assert (entry["points"]["status"][()] == 0).all()
