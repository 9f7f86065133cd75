"""Size of finished run files: what the frames take against what the file takes.

A run file holds its frames (the data), the per-point and per-frame tables, the plan,
profile and identities (kilobytes), and whatever HDF5 allocated but did not fill. This
benchmark runs small plans to the end and reports the file size next to the bytes of the
frames as stored (after compression) and of the journal.

    python benchmarks/bench_run_file_size.py          # ideal-bench plans (seconds)
    python benchmarks/bench_run_file_size.py --sim    # also the sphere capture on sim-spheres
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import h5py  # noqa: E402

from instrument.plans import build_plan, parse_plan  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402
from tests.instrument.helpers import ideal_bench, inplane_plan  # noqa: E402


def stored_frame_bytes(path: Path) -> int:
    """Bytes the frame chunks take on disk (compressed where the writer compressed)."""
    with h5py.File(path, "r") as f:
        ds = f["entry/data"].get("frames")
        if ds is None:
            return 0
        return sum(ds.id.get_chunk_info(k).size for k in range(ds.id.get_num_chunks()))


def run_ideal(folder: Path, step: float, shape: tuple[int, int]) -> Path:
    bench = ideal_bench(shape=shape)
    plan = build_plan(parse_plan(inplane_plan(step=step)), bench.profile)
    engine = start_run(plan, bench, runs_dir=folder, fsync=False, catalog=False)
    engine.run()
    return Path(engine.store.path)


def run_sim(folder: Path, plan_file: str, bench_name: str) -> Path:
    from drivers.transport import add_url_handler_package
    from instrument.bench.devices import open_bench
    from instrument.bench.profile import load_profile
    from instrument.plans import load_plan

    add_url_handler_package("hw_mocks.urlhandler")
    profile = load_profile(bench_name)
    plan = build_plan(load_plan(ROOT / plan_file), profile)
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=folder, fsync=False, catalog=False)
        engine.run()
    return Path(engine.store.path)


def report(name: str, path: Path) -> None:
    with h5py.File(path, "r") as f:
        n = int(f["entry/points/index"].shape[0])
        nf = int(f["entry/data/frame_point"].shape[0])
    size = path.stat().st_size
    frames = stored_frame_bytes(path)
    journal = Path(str(path) + ".journal").stat().st_size
    print(f"| {name} | {n} | {nf} | {size / 1024:.1f} | {frames / 1024:.1f} | "
          f"{(size - frames) / 1024:.1f} | {journal / 1024:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim", action="store_true", help="also run the sphere capture on the "
                    "emulated sphere bench (about 15 s)")
    args = ap.parse_args()
    print("| run | points | frames | file KiB | frames KiB | rest KiB | journal KiB |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        report("ideal in-plane, 17 points, 8×8 px", run_ideal(t / "a", 15.0, (8, 8)))
        report("ideal in-plane, 127 points, 8×8 px", run_ideal(t / "b", 2.0, (8, 8)))
        report("ideal in-plane, 17 points, 256×256 px", run_ideal(t / "c", 15.0, (256, 256)))
        if args.sim:
            report("sphere capture (sim-spheres), 4 points, 72×72 px",
                   run_sim(t / "d", "examples/sphere_capture.toml", "sim-spheres"))


if __name__ == "__main__":
    main()
