"""The documentation site (ADR 0093) builds with every warning an error and every
cross-reference checked, as CI builds it; and a broken reference does fail that build."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
#: What CI runs (the README's command, into a temporary folder).
STRICT = ["-W", "--keep-going", "-n", "-q", "-b", "html"]


def _sphinx(src: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sphinx", *STRICT, str(src), str(out)],
                          capture_output=True, text=True, timeout=1500)


def _small_site(tmp_path: Path, body: str) -> Path:
    """A one-page site with the real site's settings and extensions, documenting one
    module (``drivers.errors``) so that it builds in seconds."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "conf.py").write_text(
        f"import sys\nsys.path.insert(0, {str(DOCS)!r})\n"
        "from conf import *  # noqa: F403 (the site's settings)\n"
        "api_packages = ['drivers.errors']\n", encoding="utf-8")
    (src / "index.rst").write_text(
        f"Test\n====\n\n{body}\n\n.. toctree::\n\n   api/generated/drivers.errors\n",
        encoding="utf-8")
    return src


def test_a_resolvable_reference_builds(tmp_path: Path) -> None:
    src = _small_site(tmp_path, "See :class:`drivers.errors.LimitError` and "
                                ":class:`~drivers.errors.DeviceTimeout`.")
    proc = _sphinx(src, tmp_path / "html")
    assert proc.returncode == 0, proc.stderr
    page = (tmp_path / "html" / "api" / "generated" / "drivers.errors.html").read_text(
        encoding="utf-8")
    assert "LimitError" in page


def test_a_broken_cross_reference_fails_the_build(tmp_path: Path) -> None:
    src = _small_site(tmp_path, "See :func:`drivers.errors.no_such_function`.")
    proc = _sphinx(src, tmp_path / "html")
    assert proc.returncode != 0
    assert "drivers.errors.no_such_function" in proc.stderr
    assert "reference target not found" in proc.stderr


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the whole site imports and documents ~140 modules
def test_the_site_builds_strictly_with_the_api_reference(tmp_path: Path) -> None:
    out = tmp_path / "html"
    proc = _sphinx(DOCS, out)
    assert proc.returncode == 0, proc.stderr[-6000:]
    for page in ("index.html", "guide/index.html", "guide/scanning.html",
                 "architecture.html", "decisions/0093-documentation-site.html",
                 "changelog.html", "api/index.html"):
        assert (out / page).is_file(), page
    api = out / "api" / "generated"
    for module, name in (("drivers.base", "MotionAxis"), ("instrument.run.runfile", "RunData"),
                         ("instrument.plans.planfile", "PlanSpec"),
                         ("instrument.scripting.bench", "open_bench"),
                         ("instrument.pipelines.brdf.pipeline", "fit_run"),
                         ("analysis.lightfield.reconstruct", "Reconstruction")):
        page = (api / f"{module}.html").read_text(encoding="utf-8")
        assert f'id="{module}.{name}"' in page, (module, name)
