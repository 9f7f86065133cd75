"""``scatterlab examples``: the files the README and the guide use, written out of the
package (here the checkout's ``examples/``; the wheel's package data in
``tests/test_release.py``)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from instrument.cli import main
from instrument.cli.examples import PATTERNS, example_files

ROOT = Path(__file__).resolve().parents[3]


def test_patterns_agree_with_the_package_data_in_pyproject() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert tuple(config["tool"]["setuptools"]["package-data"]["instrument._examples"]) \
        == PATTERNS


def test_the_examples_the_guide_names_are_among_the_files() -> None:
    files = example_files()
    for name in ("brdf_inplane.toml", "bench_inplane_real.toml", "lightfield_scan.toml",
                 "camera_calibration_sim.json", "scripting/inplane_fit.py",
                 "notebooks/adaptive_lobe.ipynb"):
        assert name in files
    # every file of the checkout's examples/ that the patterns take, and no cache files
    assert not any("__pycache__" in rel for rel in files)


def test_copy_writes_every_file_byte_for_byte(tmp_path: Path, capsys) -> None:
    dest = tmp_path / "examples"
    assert main(["examples", "copy", str(dest)]) == 0
    files = example_files()
    for rel in files:
        assert (dest / rel).read_bytes() == (ROOT / "examples" / rel).read_bytes()
    assert f"copied {len(files)} example files" in capsys.readouterr().out


def test_copy_refuses_to_overwrite_and_writes_nothing(tmp_path: Path, capsys) -> None:
    dest = tmp_path / "ex"
    dest.mkdir()
    (dest / "brdf_inplane.toml").write_text("mine", encoding="utf-8")
    assert main(["examples", "copy", str(dest)]) == 2
    err = capsys.readouterr().err
    assert "already exist" in err and "--force" in err
    assert sorted(p.name for p in dest.iterdir()) == ["brdf_inplane.toml"]
    assert (dest / "brdf_inplane.toml").read_text(encoding="utf-8") == "mine"
    assert main(["examples", "copy", str(dest), "--force"]) == 0
    assert (dest / "brdf_inplane.toml").read_bytes() == \
        (ROOT / "examples" / "brdf_inplane.toml").read_bytes()


def test_list_prints_the_relative_paths(capsys) -> None:
    assert main(["examples", "list"]) == 0
    assert capsys.readouterr().out.split() == list(example_files())
