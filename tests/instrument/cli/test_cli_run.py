"""`scatterlab plan / run / runs / resume` end to end on the emulated `sim` bench."""

from __future__ import annotations

import h5py
import numpy as np

from instrument.cli import main

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "cli test"
[sample]
name = "sim-grey"
[scan]
theta_i = [30.0]
theta_r = [10.0, 30.0, 50.0]
[acquisition]
mode = "fixed"
exposure_us = 2000
dark = "per_point"
"""


def test_plan_dry_run_writes_coverage_png(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    png = tmp_path / "cov.png"
    assert main(["plan", str(plan), "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "3 points" in out and "estimated duration" in out and "travel" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_guard_rejection_is_an_error_not_a_traceback(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN.replace("[10.0, 30.0, 50.0]", "[-30.0, 10.0]"))
    assert main(["plan", str(plan)]) == 2
    out = capsys.readouterr().out
    assert "rejected before any motion" in out and "incident beam" in out


def test_run_on_sim_bench_then_runs_and_resume(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    out_dir = tmp_path / "runs"
    assert main(["run", str(plan), "--out", str(out_dir), "--no-fsync"]) == 0
    out = capsys.readouterr().out
    assert "run finished: 3 of 3 points" in out and "run file:" in out
    assert "angles, exposures, power readings" in out  # what this bench recorded
    path = next(out_dir.glob("*.h5"))
    with h5py.File(path, "r") as f:
        e = f["entry"]
        assert e.attrs["status"] == "finished"
        assert list(e["points/label"].asstr()[:]) == ["sample"] * 3
        assert e["data/frames"].shape[0] == 6  # one light + one dark frame per point
        light = e["data/frame_light"][:]
        assert light.sum() == 3
        assert np.all(e["points/signal"][:] > 0)  # the simulated sample scatters light
        assert np.allclose(sorted(e["points/theta_r"][:]), [10, 30, 50], atol=0.02)
        ident = e["instrument/sample_theta"].attrs
        assert ident["vendor"] == "Thorlabs" and ident["driver"] == "thorlabs_apt"
    assert main(["runs", "--out", str(out_dir)]) == 0
    listing = capsys.readouterr().out
    assert "sim-grey" in listing and "finished" in listing and "3/3" in listing
    assert main(["resume", str(path), "--out", str(out_dir)]) == 0
    assert "already finished" in capsys.readouterr().out


def test_every_example_plan_dry_runs(tmp_path, capsys):
    from pathlib import Path

    examples = Path(__file__).resolve().parents[3] / "examples"
    benches = {"brdf_hemisphere": "sim_out_of_plane", "lightfield_scan": "sim-lightfield",
               "sphere_capture": "sim-spheres", "brdf_spectral_lockin": "sim-spectral",
               "brdf_inplane_spin": str(examples / "bench_sim_laser.toml"),
               "brdf_polarimetric": "sim-polarimetric",
               "brdf_polarimetric_pem": "sim-polarimetric-pem"}
    directional = {"brdf_inplane", "brdf_inplane_spin", "brdf_lobe", "brdf_hemisphere",
                   "brdf_polarimetric", "brdf_polarimetric_pem",
                   "calibration_reference",
                   "calibration_signature", "brdf_spectral_lockin", "calibration_nd"}
    names = sorted(p.stem for p in examples.glob("*.toml")
                   if "[plan]" in p.read_text(encoding="utf-8"))  # plans, not profiles
    assert len(names) >= 10
    for name in names:
        rc = main(["plan", str(examples / f"{name}.toml"), "--bench",
                   benches.get(name, "sim"), "--png", str(tmp_path / f"{name}.png")])
        out = capsys.readouterr().out
        assert rc == 0, out
        # A coverage picture exactly for the plans that sample scattering directions.
        assert (tmp_path / f"{name}.png").exists() == (name in directional), (name, out)


def test_plan_cli_bad_arguments_are_errors_not_tracebacks(tmp_path, capsys):
    from pathlib import Path

    examples = Path(__file__).resolve().parents[3] / "examples"
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    cases = [
        # A hemispherical plan on the in-plane default bench: one message naming the fix.
        (["plan", str(examples / "brdf_hemisphere.toml")], "needs an out-of-plane bench"),
        (["plan", str(plan), "--png", str(tmp_path / "c.jpg.txt")], "must end in .png"),
        (["plan", str(plan), "--target-uncertainty", "-1"], "positive standard deviation"),
        (["plan", str(plan), "--target-uncertainty", "0.01", "--prior", "nosuch:1"],
         "unknown BRDF model 'nosuch'"),
        (["plan", str(examples / "brdf_hemisphere.toml"), "--bench", "sim_out_of_plane",
          "--target-uncertainty", "0.01"], "in-plane plans"),
    ]
    for argv, expected in cases:
        assert main(argv) == 2, argv
        captured = capsys.readouterr()
        text = captured.out + captured.err
        assert expected in text and "Traceback" not in text, (argv, text)
    assert not list(tmp_path.glob("c.jpg*"))


def test_run_and_runs_with_a_bad_out_folder_are_errors(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    assert main(["run", str(plan), "--out", str(not_a_folder)]) == 2
    assert "cannot create the folder" in capsys.readouterr().out
    # Listing an empty place says so and creates nothing.
    assert main(["runs", "--out", str(tmp_path / "none")]) == 0
    assert "no runs in" in capsys.readouterr().out
    assert not (tmp_path / "none").exists()


def test_runs_filters_from_the_command_line(tmp_path, capsys):
    import time

    from instrument.run.catalog import Catalog, RunRow

    now = time.time()
    with Catalog(tmp_path) as cat:
        for run_id, sample, kind, status, age_days in [
                ("a-old", "grey", "brdf_in_plane", "finished", 10),
                ("b-dark", "grey", "dark", "finished", 1),
                ("c-white", "white", "brdf_in_plane", "aborted", 0.5)]:
            cat.add(RunRow(run_id, sample, kind, "p", "sim", status, now - 86400 * age_days,
                           None, 3, 3, str(tmp_path / f"{run_id}.h5")))

    def listed(*argv):
        assert main(["runs", "--out", str(tmp_path), *argv]) == 0
        out = capsys.readouterr().out
        return [r for r in ("a-old", "b-dark", "c-white") if r in out]

    assert listed() == ["a-old", "b-dark", "c-white"]
    assert listed("--sample", "gre") == ["a-old", "b-dark"]
    assert listed("--kind", "brdf_in_plane", "--status", "finished") == ["a-old"]
    assert listed("--since-days", "2") == ["b-dark", "c-white"]
    assert listed("--limit", "1") == ["c-white"]  # newest first
    assert listed("--status", "paused") == []


def test_a_plan_that_moves_no_axis_runs_and_stores_its_points(tmp_path, capsys):
    """Dark frames (examples/calibration_dark.toml moves nothing): the positions table keeps
    one NaN column instead of failing to store the first point."""
    plan = tmp_path / "dark.toml"
    plan.write_text('[plan]\nkind = "dark"\nname = "dark"\n[scan]\nexposures_us = [100, 1000]\n'
                    'frames = 1\n[acquisition]\ndetectors = ["camera"]\n')
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--out", str(out), "--quiet"]) == 0
    assert "run finished: 2 of 2 points" in capsys.readouterr().out
    (run,) = out.glob("*.h5")
    with h5py.File(run, "r") as f:
        assert f["entry/points/positions"].shape == (2, 1)
        assert np.all(np.isnan(f["entry/points/positions"][()]))
        assert f["entry/data/frames"].shape[0] == 2
