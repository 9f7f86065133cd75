"""`scatterlab serve-sim --link-dir`: stable names for the ptys, a profile that uses them."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile, parse_profile
from instrument.cli import main

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "bench_serve_sim.toml"


def test_linked_ptys_open_through_the_example_profile(tmp_path, capsys):
    links = tmp_path / "ptys"
    done: list[int] = []
    server = threading.Thread(target=lambda: done.append(main(
        ["serve-sim", "--bench", "sim", "--link-dir", str(links), "--duration", "6"])),
        daemon=True)
    server.start()
    deadline = time.monotonic() + 20
    while not (links / "camera_z").is_symlink() and time.monotonic() < deadline:
        time.sleep(0.05)
    # the example profile, with its link folder replaced by this test's
    text = EXAMPLE.read_text(encoding="utf-8").replace("/tmp/scatterlab-ptys", str(links))
    profile = parse_profile(text, source="bench_serve_sim.toml")
    with open_bench(profile) as bench:
        assert set(bench.axes) == {"sample_theta", "detector_theta", "camera_z"}
        assert bench.axes["sample_theta"].identity.model == "K10CR1"
    out = capsys.readouterr().out
    assert f"(link {links / 'sample_theta'})" in out and "/dev/pts/" in out
    load_profile(EXAMPLE)  # the example as shipped validates too
    server.join(30)  # the server stops after its duration and removes its links
    assert done == [0] and not any(links.iterdir())


def test_links_are_removed_and_a_file_is_never_replaced(tmp_path, capsys):
    links = tmp_path / "ptys"
    assert main(["serve-sim", "--bench", "sim", "--link-dir", str(links),
                 "--duration", "0.2"]) == 0
    assert links.is_dir() and not any(links.iterdir())
    (links / "sample_theta").write_text("not a link")
    assert main(["serve-sim", "--bench", "sim", "--link-dir", str(links),
                 "--duration", "0.2"]) == 2
    assert "is not a link" in capsys.readouterr().out
    assert (links / "sample_theta").read_text() == "not a link"
