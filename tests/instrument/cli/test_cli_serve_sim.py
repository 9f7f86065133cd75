"""`scatterlab serve-sim --link-dir`: stable names for the ptys, a profile that uses them."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile, parse_profile
from instrument.cli import main

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "bench_serve_sim.toml"


def test_linked_ptys_open_through_the_example_profile(tmp_path):
    """The server runs until Ctrl-C (no duration to outlast on a slow machine), in its own
    process as an operator runs it; SIGINT ends it and it removes its links."""
    links = tmp_path / "ptys"
    server = subprocess.Popen(
        [sys.executable, "-m", "instrument.cli", "serve-sim", "--bench", "sim",
         "--link-dir", str(links)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        # Ctrl-C reaches it as at a console: a runner started in the background (a shell's
        # `&`, some CI agents) passes SIGINT on ignored, and Python then keeps it ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        for line in server.stdout:  # the links exist once it says it is serving
            lines.append(line)
            if line.startswith("serving"):
                break
        out = "".join(lines)
        assert f"(link {links / 'sample_theta'})" in out and "/dev/pts/" in out, out
        # the example profile, with its link folder replaced by this test's
        text = EXAMPLE.read_text(encoding="utf-8").replace("/tmp/scatterlab-ptys", str(links))
        profile = parse_profile(text, source="bench_serve_sim.toml")
        with open_bench(profile) as bench:
            assert set(bench.axes) == {"sample_theta", "detector_theta", "camera_z"}
            assert bench.axes["sample_theta"].identity.model == "K10CR1"
        load_profile(EXAMPLE)  # the example as shipped validates too
        server.send_signal(signal.SIGINT)  # Ctrl-C
        assert server.wait(60) == 0
    finally:
        if server.poll() is None:
            server.kill()
            server.wait(60)
        server.stdout.close()
    assert not any(links.iterdir())  # the server removed its links


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
