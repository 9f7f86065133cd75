"""``scatterlab run PLAN.toml``: run a plan on a bench and store it in one run file (a
two-pass lobe plan: two run files, the second naming the first)."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from instrument.run.paths import DEFAULT_RUNS_DIR

if TYPE_CHECKING:
    from instrument.bench.devices import Bench
    from instrument.bench.profile import BenchProfile
    from instrument.plans.build import Plan
    from instrument.plans.planfile import PlanSpec
    from instrument.run.engine import RunEngine

HELP = "run a plan (BRDF, light field, calibration) on a bench"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help=HELP)
    p.add_argument("plan", help="plan file (TOML), e.g. examples/brdf_inplane.toml")
    add_common(p)
    p.set_defaults(func=run)


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bench", default=None,
                   help="bench profile name or path (default: sim, or the run's own for resume)")
    p.add_argument("--out", default=str(DEFAULT_RUNS_DIR),
                   help=f"folder for run files and the catalog (default: {DEFAULT_RUNS_DIR})")
    p.add_argument("--no-fsync", action="store_true",
                   help="do not force each point to stable storage (still safe against a "
                   "crash of the program, not of the computer)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def drive(engine: RunEngine, quiet: bool) -> int:
    """Run the engine in the foreground: progress, Ctrl-C aborts cleanly, summary.

    A second Ctrl-C forces the program out at once; the journal still holds every
    committed point, so the message names the ``resume`` command that continues the run.
    """
    from instrument.cli._progress import ConsoleProgress, print_summary
    from instrument.run.engine import EngineState

    progress = ConsoleProgress()
    if quiet:
        progress.stream = open("/dev/null", "w")  # noqa: SIM115 - closed below
    engine.subscribe(progress)
    interrupted = threading.Event()

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        if interrupted.is_set():
            raise KeyboardInterrupt
        interrupted.set()
        print("\ninterrupt: stopping motion, light off, closing the run file "
              "(Ctrl-C again to force)")
        engine.abort()

    old = signal.signal(signal.SIGINT, on_sigint) \
        if threading.current_thread() is threading.main_thread() else None
    try:
        engine.start()
        while engine.wait(0.2) in (EngineState.RUNNING, EngineState.IDLE) or engine.alive:
            if engine.state is EngineState.PAUSED and progress.finished is None:
                # Nobody at a console can resume an automatic pause: stop here cleanly;
                # the run continues later with `scatterlab resume`.
                engine.stop_when_paused()
    except KeyboardInterrupt:
        print(forced_stop_message(engine.store.path))
        return 130
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
        if quiet:
            progress.stream.close()
    if progress.finished is not None:
        print_summary(progress.finished, progress.faults)
        return 0 if progress.finished.status == "finished" else 1
    return 1


def forced_stop_message(path: str | Path) -> str:
    """What a forced stop (second Ctrl-C) left, and the command that continues the run."""
    return (f"\ninterrupted before the run file was closed: every committed point is in its "
            f"journal; continue the run with:\n  scatterlab resume {path}")


def run(args: argparse.Namespace) -> int:
    from instrument.bench.devices import open_bench
    from instrument.bench.guard import GuardError
    from instrument.bench.profile import load_profile
    from instrument.plans import build_plan, load_plan
    from instrument.plans.lobe import lobe_of

    spec = load_plan(args.plan)
    profile = load_profile(args.bench or "sim")
    try:
        plan = build_plan(spec, profile)  # validated and guarded before anything opens
    except GuardError as err:
        print(f"error: {err}")
        return 2
    if plan.dropped_in_beam:
        print(f"note: {plan.dropped_in_beam} point(s) with the detector in the incident "
              "beam were left out (skip_beam_points)")
    try:
        Path(args.out).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        print(f"error: --out {args.out}: cannot create the folder for run files "
              f"({err.strerror or err})")
        return 2
    with open_bench(profile) as bench:
        engine = _start(plan, bench, args)
        if engine is None:
            return 2
        code = drive(engine, args.quiet)
        if code != 0 or lobe_of(spec) is None:
            return code
        return _second_pass(Path(engine.store.path), spec, profile, bench, args)


def _start(plan: Plan, bench: Bench, args: argparse.Namespace) -> RunEngine | None:
    """The engine of a new run file, or None with the reason printed in one line (a disk
    below the free-space margin: no run file was made)."""
    from instrument.run.runner import start_run
    from instrument.run.storage import StorageError

    try:
        return start_run(plan, bench, runs_dir=args.out, fsync=not args.no_fsync)
    except StorageError as err:
        print(f"error: {err.strerror or err}")  # the message, without "[Errno 28]"
        return None


def _second_pass(first: Path, spec: PlanSpec, profile: BenchProfile, bench: Bench,
                 args: argparse.Namespace) -> int:
    """A two-pass lobe plan (``[scan] lobe``): fit the first pass, place the second pass's
    points by Fisher information and run them (:mod:`instrument.plans.lobe`)."""
    from instrument.bench.guard import GuardError
    from instrument.pipelines.brdf.second_pass import second_pass_plan

    try:
        second = second_pass_plan(first, spec, profile)
    except (ValueError, GuardError) as err:
        print(f"error: the second pass of {first.name} could not be planned: {err}")
        return 2
    pl = second.placement
    if not second.worthwhile:
        print(second.refusal())
        print(f"first pass: {first}")
        return 0
    placed = (f"{len(pl.pairs)} geometries ({len(second.plan.points)} points)"
              if spec.polarimetry is not None else f"{len(second.plan.points)} points")
    print(f"second pass: {placed} placed by Fisher information on {second.model} fitted to "
          f"the first pass ({second.verdict})")
    if second.fitted_at:
        print(f"  {second.fitted_at}")
    filtered = sum(s >= 0 for s in pl.slots)
    if filtered or pl.not_measurable:
        print(f"  {filtered} of them read through a neutral-density filter; "
              f"{pl.not_measurable} candidate direction(s) left out (they would clip "
              "behind every filter)")
    for name in pl.sigma_first:
        print(f"  predicted σ({name}): {pl.sigma_first[name]:.3g} after the first pass, "
              f"{pl.sigma_both[name]:.3g} with the second (the fit's error budget)")
    a = second.alternative
    print(f"  a single pass of equal time (θr every {a.theta_r_step_deg:g}°, {a.n_points} "
          f"points) is predicted to give σ({second.target}) {a.sigma[second.target]:.3g}")
    engine = _start(second.plan, bench, args)
    if engine is None:
        return 2
    code = drive(engine, args.quiet)
    print(f"fit both passes: scatterlab fit {engine.store.path}")
    return code
