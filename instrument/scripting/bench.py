"""The bench as a script holds it: :func:`open_bench`, dry runs and runs.

Everything goes through the same code as ``scatterlab plan``, ``run`` and ``resume``:
plans are validated and guarded by :func:`~instrument.plans.build_plan`, runs are made by
:func:`~instrument.run.runner.start_run` (same run file, catalog row and provenance) and
driven by the same engine. Leaving the ``with`` block, or an exception or a keyboard
interrupt inside it, aborts a run still going (motion stopped, light off, file closed,
resumable) and closes the bench safe.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from instrument.bench.profile import BenchProfile, load_profile
from instrument.plans.adaptive import AdaptivePlan
from instrument.plans.build import Plan, PlanEstimate, build_plan
from instrument.plans.planfile import PlanSpec, load_plan
from instrument.run.paths import DEFAULT_RUNS_DIR
from instrument.scripting.handle import RunHandle

if TYPE_CHECKING:
    from instrument.bench.devices import Bench
    from instrument.run.engine import RunEngine
    from instrument.run.events import Event

__all__ = ["DryRun", "ScriptBench", "open_bench"]

#: A plan as a script gives it: a parsed plan (what the builders return) or the path of a
#: plan file.
PlanLike = PlanSpec | str | Path


def open_bench(profile: str | Path | BenchProfile = "sim", *,
               runs_dir: str | Path = DEFAULT_RUNS_DIR, fsync: bool = True) -> ScriptBench:
    """Open a bench: ``"sim"`` (the simulated bench), another built-in profile's name, or a
    profile file's path. Use it in a ``with`` block, which always leaves the bench safe::

        with open_bench("sim", runs_dir="runs") as bench:
            handle = bench.run(plans.load("examples/brdf_inplane.toml"))

    ``runs_dir``: where run files and the catalog go (created if missing). ``fsync``:
    force each point to stable storage (``False`` is still safe against a crash of the
    program, not of the computer).

    Raises
    ------
    ProfileError
        The profile is missing or invalid (every bad field named).
    DeviceError
        A device did not open; nothing stays open.
    """
    from instrument.bench.devices import open_bench as open_devices

    prof = profile if isinstance(profile, BenchProfile) else load_profile(str(profile))
    Path(runs_dir).mkdir(parents=True, exist_ok=True)
    return ScriptBench(open_devices(prof), Path(runs_dir), fsync=fsync)


@dataclass(frozen=True)
class DryRun:
    """What a plan would do on this bench, without moving anything (``scatterlab plan``).

    ``points``: one row per point in execution order, columns ``axes`` (targets in axis
    units; NaN where a point leaves an axis); ``angles``: (θi, φi, θr, φr) in degrees per
    point (NaN for points without a scattering direction); ``estimate``: how long it takes
    and why (:class:`~instrument.plans.PlanEstimate`; ``estimate.total_s``,
    ``estimate.travel``, ``estimate.assumed``).
    """

    plan: Plan
    estimate: PlanEstimate
    points: Any              # ndarray (n, len(axes))
    axes: tuple[str, ...]
    angles: Any              # ndarray (n, 4)
    dropped_in_beam: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n_points(self) -> int:
        return len(self.plan.points)

    @property
    def travel(self) -> dict[str, float]:
        return dict(self.estimate.travel)

    def coverage(self, path: str | Path) -> Path:
        """Draw the sampled directions (the coverage picture of ``scatterlab plan``)."""
        from instrument.plans.coverage import write_coverage_png

        return write_coverage_png(self.plan, path)

    def __repr__(self) -> str:
        return (f"<DryRun {self.plan.spec.name!r}: {self.n_points} points, "
                f"about {self.estimate.total_s:.0f} s on this bench>")


class ScriptBench:
    """An opened bench for a script. Made by :func:`open_bench`."""

    def __init__(self, bench: Bench, runs_dir: Path, *, fsync: bool = True) -> None:
        self._bench = bench
        self.runs_dir = runs_dir
        self._fsync = fsync
        self._active: RunHandle | None = None

    @property
    def profile(self) -> BenchProfile:
        return self._bench.profile

    @property
    def devices(self) -> dict[str, Any]:
        """The opened drivers by role (read-only use; runs own them while they go)."""
        return dict(self._bench.devices)

    # ------------------------------------------------------------------ plans
    def _plan(self, plan: PlanLike | AdaptivePlan) -> Plan:
        if isinstance(plan, AdaptivePlan):
            plan = plan.base  # its first points; the rest are decided during the run
        spec = plan if isinstance(plan, PlanSpec) else load_plan(plan)
        return build_plan(spec, self._bench.profile)  # validated and guarded

    def dry_run(self, plan: PlanLike | AdaptivePlan) -> DryRun:
        """Points, travel and duration of ``plan`` on this bench; nothing moves. For an
        adaptive plan, of its first points (the rest are decided during the run).

        Raises :class:`~instrument.bench.guard.GuardError` with the guard's reasons when
        a point is not allowed, as ``run`` would before anything moves.
        """
        return dry_run_of(self._plan(plan))

    # ------------------------------------------------------------------- runs
    def run(self, plan: PlanLike | AdaptivePlan, *, block: bool = True,
            progress: bool | None = None,
            on_event: Callable[[Event], Any] | None = None) -> RunHandle:
        """Run ``plan`` (a plan object, a plan file, or an adaptive plan such as
        ``plans.sharp_lobe(...)``, :mod:`instrument.plans.adaptive`) into a new run file.
        An adaptive run's progress counts the points planned so far.

        ``block``: wait for the end, showing a progress bar (``progress``, default on with
        ``block``; tqdm's notebook bar in Jupyter when tqdm is installed). A pause the
        engine makes itself (a fault that needs an answer, a full disk) ends a blocking
        call with the run stopped resumable, as ``scatterlab run`` does: nobody is there
        to answer it. Interrupting a blocking call (Ctrl-C, the notebook's stop button)
        aborts the run cleanly and re-raises. With ``block=False`` the handle returns at
        once: poll ``handle.progress``, iterate ``handle.events()``, or ``wait()``.
        ``on_event(event)`` is called on the engine's thread for every event: it must
        return quickly.

        Raises
        ------
        PlanError, GuardError
            Before anything moves or any file is made.
        RuntimeError
            Another run of this bench is still going.
        """
        from instrument.run.runner import start_run

        if self._active is not None and not self._active.done:
            raise RuntimeError(f"{self._active.path.name} is still running on this bench; "
                               "wait() for it or abort() it first")
        built = self._plan(plan)
        engine = start_run(built, self._bench, runs_dir=self.runs_dir, fsync=self._fsync,
                           adaptive=plan if isinstance(plan, AdaptivePlan) else None)
        return self._drive(engine, block=block, progress=progress, on_event=on_event)

    def resume(self, path: str | Path, *, block: bool = True, progress: bool | None = None,
               on_event: Callable[[Event], Any] | None = None,
               adaptive: AdaptivePlan | None = None) -> RunHandle:
        """Continue an interrupted run in its own file (``scatterlab resume``): the
        points its journal holds are kept, the missing ones measured. An adaptive run's
        plan is rebuilt from the file (or is ``adaptive``, for a plan class this program
        has not registered) and asked again from where it was."""
        from instrument.run.runner import resume_run

        engine = resume_run(path, self._bench, fsync=self._fsync, adaptive=adaptive)
        return self._drive(engine, block=block, progress=progress, on_event=on_event)

    def _drive(self, engine: RunEngine, *, block: bool, progress: bool | None,
               on_event: Callable[[Event], Any] | None) -> RunHandle:
        handle = RunHandle(engine, on_event=on_event)
        bar = _progress_bar(handle) if (block if progress is None else progress) else None
        self._active = handle
        engine.start()
        if not block:
            return handle
        try:
            for ev in handle.events():
                if bar is not None:
                    bar(ev)
                if handle.paused_by_the_engine(ev):
                    engine.stop_when_paused()
            handle.wait()
        except BaseException:
            handle.abort(timeout=None)
            raise
        finally:
            if bar is not None:
                bar(None)
        return handle

    # ------------------------------------------------------------------ close
    def close(self) -> None:
        """Abort a run still going, then stop every axis, light off, devices closed."""
        if self._active is not None and not self._active.done:
            self._active.abort(timeout=None)
        self._bench.close()

    def __enter__(self) -> ScriptBench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<ScriptBench {self.profile.name!r}: {len(self._bench.devices)} devices>"


def dry_run_of(built: Plan) -> DryRun:
    """The :class:`DryRun` of a plan built (and guarded) for a bench."""
    import numpy as np

    nan4 = (np.nan,) * 4
    angles = np.array([nan4 if (a := p.angles) is None
                       else (a.theta_i, a.phi_i, a.theta_r, a.phi_r)
                       for p in built.points], dtype=float).reshape(-1, 4)
    return DryRun(built, built.estimate(), built.targets_array(), built.axes, angles,
                  built.dropped_in_beam)


def _progress_bar(handle: RunHandle) -> Callable[[Event | None], None]:
    """A progress callback: tqdm (its notebook widget under Jupyter) when installed, else a
    line on stderr every 10 %. Called with each event, and with None at the end."""
    from instrument.run.events import Progress, RunFinished

    total = handle.progress.n_total
    try:
        from tqdm.auto import tqdm
    except ImportError:
        tqdm = None
    if tqdm is not None:
        bar = tqdm(total=total, desc=handle.path.stem, unit="pt")

        def update(ev: Event | None) -> None:
            if isinstance(ev, Progress):
                bar.n = ev.n_done
                bar.refresh()
            elif isinstance(ev, RunFinished):
                bar.n = ev.n_done
                bar.set_postfix_str(ev.status)
            elif ev is None:
                bar.close()
        return update

    shown = [-1]

    def line(ev: Event | None) -> None:
        if isinstance(ev, Progress) and ev.n_total:
            tenth = 10 * ev.n_done // ev.n_total
            if tenth > shown[0]:
                shown[0] = tenth
                print(f"{handle.path.stem}: {ev.n_done}/{ev.n_total} points",
                      file=sys.stderr)
        elif isinstance(ev, RunFinished):
            print(f"{handle.path.stem}: {ev.status}, {ev.n_done}/{ev.n_total} points",
                  file=sys.stderr)
    return line
