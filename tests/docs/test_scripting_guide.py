"""The user guide's chapter "Scripting scans in Python" (docs/guide/scripting.md): every
Python block runs, in order, in one namespace, on the simulated bench; and scripts need
only the public facade (``from instrument import ...``), never the modules behind it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CHAPTER = ROOT / "docs" / "guide" / "scripting.md"
SCRIPTS = sorted((ROOT / "examples" / "scripting").glob("*.py"))
_FENCE = re.compile(r"^```python\n(.*?)^```", re.MULTILINE | re.DOTALL)
#: What a script may import from the project: the facade, and the event classes it
#: receives (documented in the chapter).
PUBLIC = {"instrument", "instrument.run.events"}


def python_blocks(text: str) -> list[str]:
    return [m.group(1) for m in _FENCE.finditer(text)]


def project_imports(code: str) -> set[str]:
    mods = set()
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.Import):
            mods |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            mods.add(node.module)
    return {m for m in mods if m.split(".")[0] in ("instrument", "drivers", "analysis",
                                                   "gui", "hw_mocks")}


def test_the_chapter_and_the_example_scripts_use_only_the_facade():
    sources = {str(CHAPTER): "\n".join(python_blocks(CHAPTER.read_text()))}
    sources.update({str(p): p.read_text() for p in SCRIPTS})
    for where, code in sources.items():
        assert project_imports(code) <= PUBLIC, (where, project_imports(code) - PUBLIC)
    assert SCRIPTS, "examples/scripting/ holds the example scripts"


@pytest.mark.slow
def test_every_python_block_of_the_chapter_runs(tmp_path, monkeypatch, capsys):
    from tests.instrument.server.helpers import ServerProcess, fast_profile_text

    monkeypatch.chdir(tmp_path)
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    # the server the section "The same script against the bench server" connects to
    profile = tmp_path / "sim-fast.toml"
    profile.write_text(fast_profile_text(), encoding="utf-8")
    server = ServerProcess(profile, tmp_path / "server-runs")
    monkeypatch.setenv("SCATTERLAB_SERVER", server.url)
    monkeypatch.delenv("SCATTERLAB_KEY", raising=False)
    namespace: dict = {}
    blocks = python_blocks(CHAPTER.read_text())
    assert len(blocks) >= 8
    try:
        for k, code in enumerate(blocks):
            exec(compile(code, f"{CHAPTER.name} block {k + 1}", "exec"), namespace)
    finally:
        server.kill()
    out = capsys.readouterr().out
    assert "finished" in out and "1/sr" in out
    assert (tmp_path / "runs" / "brdf.png").stat().st_size > 1000
    assert namespace["handle"].status == "finished"


NOTEBOOKS = sorted((ROOT / "examples" / "notebooks").glob("*.ipynb"))


def test_the_notebooks_are_stored_without_outputs_and_use_only_the_facade():
    import nbformat

    assert NOTEBOOKS
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert all(not c.outputs and c.execution_count is None for c in code), path
        assert project_imports("\n".join(c.source for c in code)) <= PUBLIC, path


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_every_notebook_runs_on_the_simulated_bench(path, tmp_path):
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=900, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors, errors
    assert list((tmp_path / "runs").glob("*.h5"))
