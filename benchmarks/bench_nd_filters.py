"""The sharp sample's specular peak with and without the sim bench's ND filters.

The sharp sample (Lambert ρ 0.3 + GGX ks 0.5, α 0.05) on the ``sim`` bench (stages 400×
faster than real), the README's default plan ``examples/brdf_inplane.toml`` (57 points,
1024² px camera, HDR auto-exposure down to 10 µs), through the engine, drivers and firmware
emulators:

1. without the filter wheel (the bench as it was before ADR 0018): the peak's readings
   clip and are left out;
2. with the wheel of ND filters: the engine reads a clipping point again through the next
   denser filter;
3. the ND calibration plan ``examples/calibration_nd.toml`` on the same bench;

then ``scatterlab fit`` of (1), of (2) with the nominal transmissions and of (2) with the
calibration run (``--models lambert+ggx --no-cv``: the true family, so that σ(α) compares
like with like). Prints, per fit, the clipped readings, the readings through a filter,
χ²/dof, each parameter with its σ and its z against the truth, and each run's duration.

Run: ``python benchmarks/bench_nd_filters.py [--out DIR]`` (about 30 min on the 2-core
dev box under load: the camera renders its pupil at 1024² px, ~1 s a frame).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.cli import main  # noqa: E402
from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run  # noqa: E402
from instrument.run.runfile import read_run  # noqa: E402

TRUTH = {"lambert.rho": 0.3, "ggx.ks": 0.5, "ggx.alpha": 0.05}


def benches(out: Path) -> tuple[Path, Path]:
    text = (ROOT / "instrument" / "bench" / "profiles" / "sim.toml").read_text(encoding="utf-8")
    text = text.replace('"lambert.rho" = 0.5, "ggx.ks" = 0.2, "ggx.alpha" = 0.2',
                        '"lambert.rho" = 0.3, "ggx.ks" = 0.5, "ggx.alpha" = 0.05')
    text = text.replace("speed=20", "speed=400")
    sharp = out / "sharp.toml"
    sharp.write_text(text, encoding="utf-8")
    bare = out / "sharp-no-wheel.toml"
    bare.write_text(re.sub(r"\[(devices|simulation)\.filter_wheel\].*?\n\n", "", text,
                           flags=re.S), encoding="utf-8")
    return sharp, bare


def run(plan: Path, bench: Path, out: Path) -> tuple[Path, float]:
    t0 = time.perf_counter()
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    return path, time.perf_counter() - t0


def fit(path: Path, *extra: str) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["fit", str(path), "--models", "lambert+ggx", "--no-cv", "--no-write", *extra])
    return buf.getvalue()


def summary(name: str, path: Path, text: str) -> None:
    run_data = read_run(path)
    rows = run_data.brdf_rows()
    nd = run_data.nd_position
    behind = 0 if nd is None else int((nd[rows] >= 0).sum())
    clipped = int(reduce_run(path, ReductionOptions()).points.clipped.sum())
    chi = re.search(r"χ²/dof = ([\d.e+-]+) for (\d+) dof", text)
    print(f"\n## {name}: {path.name}")
    print(f"readings through an ND filter: {behind} of {rows.size}; clipped and left out: "
          f"{clipped}; χ²/dof "
          f"{chi.group(1) if chi else '?'} for {chi.group(2) if chi else '?'} dof")
    for key, truth in TRUTH.items():
        m = re.search(rf"^\s+{re.escape(key)}\s+([-\d.e+]+) ± ([\d.e+-]+)", text, re.M)
        if m:
            v, s = float(m.group(1)), float(m.group(2))
            print(f"  {key:12s} {v:.7g} ± {s:.2g}  z = {(v - truth) / s:+.2f}")
    for line in text.splitlines():
        if line.startswith("warning: ND") or "nd_filters" in line:
            print("  " + line)


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench-nd"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    sharp, bare = benches(args.out)
    plan = ROOT / "examples" / "brdf_inplane.toml"
    before, t_before = run(plan, bare, args.out / "runs-no-wheel")
    after, t_after = run(plan, sharp, args.out / "runs-nd")
    cal, t_cal = run(ROOT / "examples" / "calibration_nd.toml", sharp, args.out / "runs-cal")
    print(f"durations: without wheel {t_before:.0f} s, with ND filters {t_after:.0f} s, "
          f"ND calibration {t_cal:.0f} s")
    summary("without the wheel (before)", before, fit(before))
    summary("ND filters, nominal transmissions", after, fit(after))
    summary("ND filters, calibrated", after, fit(after, "--nd-calibration", str(cal)))


if __name__ == "__main__":
    main_()
