"""Starting and resuming runs: plan + bench → run file, catalog row and engine.

The CLI and the GUI both go through here, so a run started either way has the same file
layout, catalog entry and provenance.
"""

from __future__ import annotations

import json
import math
import secrets
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers.base import Camera, LightSource, MotionAxis, PowerMeter
from drivers.errors import DeviceError
from instrument.bench.devices import Bench
from instrument.bench.kinematics import Angles
from instrument.bench.profile import FieldError
from instrument.plans.adaptive import AdaptiveDriver, AdaptivePlan, rebuild
from instrument.plans.build import Plan
from instrument.plans.commands import ScanPoint
from instrument.plans.planfile import PlanError, parse_plan
from instrument.run.catalog import Catalog, RepairRow, RunRow
from instrument.run.engine import RunEngine
from instrument.run.events import Event, Paused, Progress, RunFinished, RunStarted
from instrument.run.health import inspect_run_file
from instrument.run.journal import read_journal
from instrument.run.layout import STATUS_OK, journal_path
from instrument.run.paths import DEFAULT_RUNS_DIR
from instrument.run.recovery import RecoveryReport, journal_usable, recover, salvage
from instrument.run.runfile import open_run, read_planned
from instrument.run.storage import RunHeader, RunStore
from instrument.version import software_version

__all__ = ["DEFAULT_RUNS_DIR", "new_run_id", "plan_from_run", "recover_run", "resume_run",
           "start_run"]




def new_run_id(kind: str) -> str:
    """Sortable and unique: ``20260122-061502-brdf_in_plane-3fa2``."""
    return f"{time.strftime('%Y%m%d-%H%M%S')}-{kind}-{secrets.token_hex(2)}"


def _nx_class(device: object) -> str:
    if isinstance(device, MotionAxis):
        return "NXpositioner"
    if isinstance(device, Camera):
        return "NXdetector"
    if isinstance(device, PowerMeter):
        return "NXmonitor"
    if isinstance(device, LightSource):
        return "NXsource"
    return "NXcollection"


def static_axis_positions(bench: Bench, moved: tuple[str, ...]) -> dict[str, Any]:
    """Where the axes the plan does not move stand at the start, and whether homed.

    They set the geometry as much as the moved ones (the camera stage sets the receiver
    distance), so they are recorded as ``axis_position.<role>`` (axis units) and
    ``axis_homed.<role>``; an unhomed axis's position is its controller counter, not a
    physical position, and analysis must not trust it.
    """
    out: dict[str, Any] = {}
    for role, axis in bench.axes.items():
        if role in moved:
            continue
        try:
            status = axis.status()
        except DeviceError:
            continue
        out[f"axis_position.{role}"] = float(status.position)
        out[f"axis_homed.{role}"] = int(bool(status.is_homed))
    return out


def camera_settings(cam: Camera) -> dict[str, str]:
    """The camera's gain (the device's units: dB for the simulated camera) and pixel format
    as a run starts, for its instrument metadata: a radiometric calibration holds for these
    settings only (:meth:`instrument.run.runfile.RunData.camera_calibration`). The engine
    changes neither during a run."""
    try:
        return {"gain": repr(float(cam.gain)), "pixel_format": cam.pixel_format.name}
    except DeviceError as err:
        return {"settings_error": str(err)}


def header_for(plan: Plan, bench: Bench, run_id: str) -> RunHeader:
    identities: dict[str, dict[str, str]] = {}
    for role, dev in bench.devices.items():
        try:
            identities[role] = {k: str(v) for k, v in dev.identity.as_dict().items()}
        except (DeviceError, AttributeError) as err:
            identities[role] = {"error": str(err)}
        spec = bench.profile.devices.get(role)
        if spec is not None:
            identities[role].update(driver=spec.driver, url=spec.url)
        if isinstance(dev, Camera):
            identities[role].update(camera_settings(dev))
    pts = plan.points
    targets = plan.targets_array().tolist()
    angles = [list(p.angles.as_tuple()) if p.angles else [math.nan] * 4 for p in pts]
    geometry = {k: v for k, v in vars(bench.profile.geometry).items()
                if isinstance(v, str | int | float)}
    geometry["detector_solid_angle_sr"] = bench.profile.geometry.detector_solid_angle_sr
    geometry.update(static_axis_positions(bench, plan.axes))
    return RunHeader(
        run_id=run_id, plan_kind=plan.kind, plan_name=plan.spec.name,
        plan_text=plan.spec.source_text, profile_text=bench.profile.source_text,
        bench_name=bench.profile.name, sample_name=plan.spec.sample_name,
        sample_description=plan.spec.sample_description, axes=plan.axes,
        planned_targets=targets, planned_angles=angles,
        planned_label=[p.label for p in pts], planned_light=[p.light for p in pts],
        planned_exposure_us=[math.nan if p.exposure_us is None else p.exposure_us
                             for p in pts],
        planned_meta=([json.dumps([list(kv) for kv in p.meta]) for p in pts]
                      if any(p.meta for p in pts) else []),
        acquisition_policy=plan.spec.acquisition.as_json(),
        retry_policies=json.dumps({r: d.retry.as_dict()
                                   for r, d in bench.profile.devices.items()}),
        identities=identities, device_kinds={r: _nx_class(d) for r, d in bench.devices.items()},
        geometry=geometry, calibration=dict(plan.spec.calibration),
        software_version=software_version(), created=time.time(),
        optical_train=optical_train_json(plan))


def optical_train_json(plan: Plan) -> str:
    """The optical train's provenance of a polarimetric plan (the profile's nominal
    ``[optics]`` and the plan's ``[polarimetry]``; in PEM mode with the amplitude set and
    the settings ``[polariser, analyser retarder, PEM axis, analyser polariser]`` (deg)
    that the points' ``pem_setting`` indexes), JSON; empty for any other plan."""
    optics = plan.profile.optics
    if plan.spec.polarimetry is None or optics is None:
        return ""
    pol = dict(plan.spec.polarimetry)
    if pol["mode"] == "pem":
        # the settings the points' pem_setting index into, and the amplitude they set
        from instrument.plans.polarimetry_pem import pem_train, plan_settings, plan_waves

        train = pem_train(plan.profile)
        pol["amplitude_waves"] = plan_waves(pol, plan.profile, train)
        pol["settings"] = [[s.polariser_deg, s.analyser_retarder_deg, s.pem_axis_deg,
                            s.analyser_polariser_deg] for s in plan_settings(pol, train)]
    return json.dumps({"optics": optics.as_dict(), "polarimetry": pol}, sort_keys=True)


#: Seconds between catalog updates of a running run's point count (a short SQLite write
#: on the worker thread; more often would cost per-point time for no reader's benefit).
CATALOG_PROGRESS_S = 2.0


def _track(engine: RunEngine, catalog: Catalog, run_id: str) -> None:
    """Keep the catalog row's status and point count current (start, progress every
    ``CATALOG_PROGRESS_S``, pause, end)."""
    last = [0.0]

    def on_event(ev: Event) -> None:
        if isinstance(ev, Progress):
            now = time.monotonic()
            if now - last[0] >= CATALOG_PROGRESS_S:
                last[0] = now
                catalog.update(run_id, n_points=ev.n_done)
        elif isinstance(ev, RunStarted):
            last[0] = time.monotonic()
            catalog.update(run_id, status="running", n_points=ev.n_done)
        elif isinstance(ev, Paused):
            catalog.update(run_id, status="paused", n_points=engine.n_done)
        elif isinstance(ev, RunFinished):
            catalog.update(run_id, status=ev.status, n_points=ev.n_done, ended=time.time())

    engine.subscribe(on_event)


def check_bench_for_plan(plan: Plan, bench: Bench) -> None:
    """Refuse, before any file or motion, a plan the bench cannot acquire.

    Raises
    ------
    PlanError
        A detector the policy names is missing, or dark frames are asked for and the bench
        has no source to turn off.
    """
    pol = plan.spec.acquisition
    errors = []
    if pol.uses_camera and bench.camera is None:
        errors.append(FieldError("acquisition.detectors",
                                 f"bench {bench.profile.name!r} has no camera"))
    if pol.uses_power_meter and bench.power_meter is None:
        errors.append(FieldError("acquisition.detectors",
                                 f"bench {bench.profile.name!r} has no power meter"))
    if pol.uses_lockin and getattr(bench, "lockin", None) is None:
        errors.append(FieldError("acquisition.detectors",
                                 f"bench {bench.profile.name!r} has no lock-in amplifier"))
    needs_dark = pol.dark != "none" or any(not p.light for p in plan.points)
    if needs_dark and bench.source is None:
        errors.append(FieldError("acquisition.dark", f"bench {bench.profile.name!r} has no "
                                 "light source to turn off for dark frames"))
    missing = [r for r in plan.axes if r not in bench.axes]
    if missing:
        errors.append(FieldError("scan", f"bench {bench.profile.name!r} has no axis "
                                 f"{', '.join(missing)}"))
    if errors:
        raise PlanError(f"plan {plan.spec.name!r} on bench {bench.profile.name!r}", errors)


def start_run(plan: Plan, bench: Bench, *, runs_dir: str | Path = DEFAULT_RUNS_DIR,
              fsync: bool = True, sync_interval_s: float = 0.25,
              min_free_bytes: int = 64 << 20, catalog: bool = True,
              run_id: str | None = None, adaptive: AdaptivePlan | None = None,
              wait: Callable[[float], object] = time.sleep) -> RunEngine:
    """Create the run file and catalog row; return the (not yet started) engine.

    With ``adaptive`` (:mod:`instrument.plans.adaptive`), ``plan`` is its base plan built
    for this bench, and the run asks the adaptive plan for more points when they are done.
    ``wait`` is the engine's (:class:`~instrument.run.engine.RunEngine`).
    """
    check_bench_for_plan(plan, bench)
    runs_dir = Path(runs_dir).resolve()  # messages name the file unambiguously
    run_id = run_id or new_run_id(plan.kind)
    header = header_for(plan, bench, run_id)
    if adaptive is not None:
        header = replace(header, adaptive=json.dumps(adaptive.describe()))
    path = runs_dir / f"{run_id}.h5"
    store = RunStore.create(path, header, fsync=fsync, sync_interval_s=sync_interval_s,
                            min_free_bytes=min_free_bytes)
    engine = RunEngine(bench, plan, store, reopen_store=_reopener(
        path, fsync=fsync, sync_interval_s=sync_interval_s, min_free_bytes=min_free_bytes,
        catalog=catalog), adaptive=None if adaptive is None else AdaptiveDriver(adaptive),
        wait=wait)
    if catalog:
        cat = Catalog(runs_dir)
        cat.add(RunRow(run_id, plan.spec.sample_name, plan.kind, plan.spec.name,
                       bench.profile.name, "created", header.created, None, 0,
                       len(plan.points), str(path.resolve())))
        _track(engine, cat, run_id)
    return engine


def plan_from_run(path: str | Path, bench: Bench) -> Plan:
    """The plan of a run, exactly as stored (points, order, policy), on ``bench``."""
    stored = read_planned(path)
    spec = parse_plan(stored.plan_text, source=f"plan stored in {path}")
    points = []
    for k, label in enumerate(stored.label):
        tg = tuple((r, float(stored.targets[k, j])) for j, r in enumerate(stored.axes)
                   if not math.isnan(stored.targets[k, j]))
        a = None if math.isnan(stored.angles[k, 0]) else Angles(*map(float, stored.angles[k]))
        e = None if math.isnan(stored.exposure_us[k]) else float(stored.exposure_us[k])
        meta = (tuple(tuple(kv) for kv in json.loads(stored.meta[k])) if stored.meta
                else ())
        points.append(ScanPoint(k, tg, a, label, bool(stored.light[k]), e, meta))
    return Plan(replace(spec), bench.profile, stored.axes, tuple(points))


def _adaptive_driver(path: Path, plan: Plan, description: str,
                     given: AdaptivePlan | None) -> AdaptiveDriver:
    """The driver of a resumed adaptive run, replayed through its stored decisions."""
    if given is None:
        # the adaptive plans this package ships register themselves on import (here, not
        # in instrument.plans.adaptive, which they import)
        import instrument.plans.adaptive_lobe  # noqa: F401
    obj = given if given is not None else rebuild(description)
    records, _ = read_journal(journal_path(path))
    stored = [r for r in records if r.get("t") == "planned"]
    n_base = stored[0]["first"] if stored else len(plan.points)
    driver = AdaptiveDriver(obj)
    with open_run(path) as f:
        pts = f["entry/points"]
        index = pts["index"][()]
        status = pts["status"][()]
        signal = pts["signal"][()]
        angles = np.stack([pts[k][()] for k in ("theta_i", "phi_i", "theta_r", "phi_r")], -1)
    for k in np.argsort(index, kind="stable"):
        a = None if np.isnan(angles[k, 0]) else angles[k]
        driver.observe_point(int(index[k]), a, float(signal[k]), int(status[k]) == STATUS_OK)
    driver.replay(replace(plan, points=plan.points[:n_base]), stored)
    return driver


def recover_run(path: str | Path, *, catalog: bool = True) -> RecoveryReport:
    """Make a run file agree with its journal (:func:`~instrument.run.recovery.recover`),
    or, when the journal is missing or unreadable and the file is a scatterlab run, rebuild
    both from what the file holds (:func:`~instrument.run.recovery.salvage`); every repair
    goes into the catalog of the run's folder.

    Raises
    ------
    StorageError
        The file is missing, not a scatterlab run, or held open by a run.
    """
    path = Path(path).resolve()
    if not journal_usable(path) and inspect_run_file(path).is_run:
        report = salvage(path)
    else:
        report = recover(path)
    if catalog and report.repaired:
        record_repair(path, report)
    return report


def record_repair(path: Path, report: RecoveryReport) -> None:
    """Put a repair into the catalog of the run's folder (adding the run if it is not
    listed there)."""
    h = report.header
    with Catalog(path.parent) as cat:
        if cat.get(h.run_id) is None:
            cat.add(RunRow(h.run_id, h.sample_name, h.plan_kind, h.plan_name, h.bench_name,
                           report.status, h.created, None, report.n_points,
                           len(h.planned_label), str(path)))
        cat.add_repair(RepairRow(h.run_id, time.time(), report.repairs, report.points_lost,
                                 None if report.original is None else str(report.original)))


def _reopener(path: Path, *, fsync: bool, sync_interval_s: float, min_free_bytes: int,
              catalog: bool, remeasure: bool = False,
              ) -> Callable[[], tuple[RunStore, set[int]]]:
    """How the engine reopens the run file after a storage error: recover it (recording
    any repair in the catalog), open it to append; with ``remeasure`` the points whose
    frames are lost are still to do."""
    def reopen() -> tuple[RunStore, set[int]]:
        report = recover_run(path, catalog=catalog)
        store, done = RunStore.reopen(path, fsync=fsync, sync_interval_s=sync_interval_s,
                                      min_free_bytes=min_free_bytes)
        store.repairs = report.repairs + store.repairs
        return store, (done - set(store.lost)) if remeasure else done
    return reopen


def resume_run(path: str | Path, bench: Bench, *, fsync: bool = True,
               sync_interval_s: float = 0.25, min_free_bytes: int = 64 << 20,
               catalog: bool = True, remeasure_lost: bool = False,
               adaptive: AdaptivePlan | None = None) -> RunEngine:
    """Recover the run file from its journal and return an engine for the missing points.

    With ``remeasure_lost`` the points whose frames a damaged file lost are measured
    again too, into the same file (their rows are rewritten; the journal keeps both
    records, the newer one stands). Raises :class:`StorageError` when there is nothing
    to resume from (see :func:`recover_run`).

    An adaptive run (ADR 0091) rebuilds its plan from the description the file holds
    (or takes ``adaptive``, the same plan made by the caller), asks it again through the
    stored decisions with the stored measurements, and goes on asking it after the
    stored points. Raises :class:`~instrument.plans.adaptive.UnknownAdaptivePlan` or
    :class:`~instrument.plans.adaptive.AdaptiveReplayError` before anything moves when
    that is not possible.
    """
    path = Path(path).resolve()
    report = recover_run(path, catalog=catalog)
    plan = plan_from_run(path, bench)
    check_bench_for_plan(plan, bench)
    driver = (_adaptive_driver(path, plan, report.header.adaptive, adaptive)
              if report.header.adaptive else None)
    store, done = RunStore.reopen(path, fsync=fsync, sync_interval_s=sync_interval_s,
                                  min_free_bytes=min_free_bytes)
    again = set(store.lost) if remeasure_lost else set()
    event: dict[str, Any] = {"kind": "resumed", "n_done": len(done - again)}
    if again:
        event["remeasure"] = sorted(again)
    store.event(event)
    engine = RunEngine(bench, plan, store, done=done - again, reopen_store=_reopener(
        path, fsync=fsync, sync_interval_s=sync_interval_s, min_free_bytes=min_free_bytes,
        catalog=catalog, remeasure=remeasure_lost), adaptive=driver)
    if catalog:
        cat = Catalog(path.parent)
        h = store.header
        if cat.get(h.run_id) is None:
            cat.add(RunRow(h.run_id, h.sample_name, h.plan_kind, h.plan_name, h.bench_name,
                           "paused", h.created, None, len(done), len(plan.points),
                           str(path.resolve())))
        _track(engine, cat, h.run_id)
    return engine
