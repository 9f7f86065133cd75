"""The one reader of run files: points, frames, header, bench profile and plan.

A run file is written by :mod:`instrument.run.storage` (NeXus-style layout, ADR 0010):
``/entry/points`` (one row per completed point, completion order), ``/entry/data/frames``
with the per-frame tables ``frame_point``, ``frame_exposure_us``, ``frame_light``,
``frame_saturated``, ``/entry/plan`` (plan text, axes, the planned points),
``/entry/instrument`` (bench profile, device identities, geometry) and
``/entry/calibration``. Everything that reads a run — the analysis pipelines, ``resume``,
the CLI's summaries — reads it through this module, with plain h5py and read-only.

A file that cannot be read as a run (missing, not HDF5, not a run, damaged, still being
written) raises :class:`RunFileError` with the words of
:func:`instrument.run.health.inspect_run_file`, the same in every command;
:func:`check_run_file` also refuses a run of a kind the analysis does not handle, naming
the command that does.

Angles are in degrees, as stored. A point's frames are its light brackets followed by one
dark frame per bracket at the same exposure (``dark = "per_point"``); with
``dark = "start"`` the dark-labelled points of the run are the master darks, matched by
exposure (:meth:`RunData.frames_of`).
"""

from __future__ import annotations

import contextlib
import json
import math
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.bench.camera_calibration import CameraCalibration, camera_calibration_for
from instrument.plans.planfile import PlanSpec, parse_plan
from instrument.run.health import inspect_run_file
from instrument.run.layout import DETECTOR_FIELDS, FRAMES_LOST, STATUS_OK, STATUS_SKIPPED

__all__ = ["ANALYSES", "PlannedPoints", "RunData", "RunFileError", "RunSummary", "as_text",
           "check_run_file", "open_run", "read_attributes", "read_events", "read_plan_kind",
           "read_planned", "read_run", "read_summary"]


class RunFileError(ValueError):
    """A file that is not a complete scatterlab run file (the message names what is missing)."""


#: The analysis commands and the plan kinds each analyses.
ANALYSES: dict[str, tuple[str, ...]] = {
    "fit": ("brdf_in_plane", "brdf_hemisphere", "reference", "signature"),
    "reconstruct": ("lightfield",),
    "locate": ("lightfield",),
    "spheres": ("sphere_capture",),
}
#: What each analysis analyses, in words.
_ANALYSED = {"fit": "BRDF runs", "reconstruct": "lightfield runs",
             "locate": "lightfield runs", "spheres": "sphere-capture runs"}
#: A plan kind in words, and what to do with a run of that kind.
_KINDS: dict[str, tuple[str, str]] = {
    "brdf_in_plane": ("an in-plane BRDF run", "use scatterlab fit"),
    "brdf_hemisphere": ("a hemispherical BRDF run", "use scatterlab fit"),
    "reference": ("a reference-standard run", "use scatterlab fit (or give it to "
                  "scatterlab fit --method relative --reference)"),
    "signature": ("an instrument-signature run", "give it to scatterlab fit --signature"),
    "lightfield": ("a lightfield run", "use scatterlab reconstruct / scatterlab locate"),
    "sphere_capture": ("a sphere-capture run", "use scatterlab spheres"),
    "dark": ("a dark-frame calibration run", "name it in a plan's [calibration] dark = ..."),
    "flat_field": ("a flat-field calibration run", "give it to scatterlab fit --flat"),
    "photon_transfer": ("a photon-transfer calibration run", "it calibrates the camera "
                        "(gain and noise); it is not analysed by itself"),
}


def kind_in_words(kind: str) -> str:
    """'a lightfield run', or "a run of plan kind 'x'" for a kind this does not know."""
    return _KINDS.get(kind, (f"a run of plan kind {kind!r}", ""))[0]


def check_run_file(path: str | Path, analysis: str | None = None, *,
                   kinds: tuple[str, ...] | None = None, role: str | None = None) -> str:
    """Check, before anything else is read, that ``path`` is a readable run file of a kind
    ``analysis`` (a key of :data:`ANALYSES`) or ``kinds`` handles; return its plan kind.

    ``role`` names the file on the command line (``--flat``) in the message.

    Raises
    ------
    RunFileError
        Missing, not a run, damaged, still being written (the words of
        :func:`instrument.run.health.inspect_run_file`), or of another kind: "… is a
        lightfield run; `scatterlab fit` analyses BRDF runs: use scatterlab reconstruct /
        scatterlab locate".
    """
    state = inspect_run_file(path)
    prefix = f"{role}: " if role else ""
    if not state.ok:
        raise RunFileError(prefix + state.message)
    allowed = kinds if kinds is not None else ANALYSES.get(analysis or "", ())
    kind = state.plan_kind
    if allowed and kind not in allowed:
        todo = _KINDS.get(kind, ("", ""))[1]
        wanted = (_ANALYSED[analysis] if kinds is None and analysis in _ANALYSED
                  else " or ".join(kind_in_words(k).removeprefix("a ").removeprefix("an ")
                                   .replace(" run", " runs") for k in allowed))
        who = f"`scatterlab {analysis}` analyses" if analysis else f"{role or 'this'} needs"
        plural = "s" if len(allowed) > 1 else ""
        raise RunFileError(f"{prefix}{path} is {kind_in_words(kind)}; {who} {wanted} "
                           f"(plan kind{plural} {', '.join(allowed)})"
                           + (f": {todo}" if todo else ""))
    return kind


@contextlib.contextmanager
def open_run(path: str | Path) -> Iterator[h5py.File]:
    """A run file open read-only; :class:`RunFileError` in words when it cannot be."""
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        state = inspect_run_file(path)
        raise RunFileError(state.message or f"{path} cannot be read as a run file"
                           ) from err
    with f:
        yield f


def as_text(value: Any) -> str:
    """An HDF5 string attribute or dataset value as ``str`` (h5py gives bytes or str)."""
    return value.decode() if isinstance(value, bytes) else str(value)


# ------------------------------------------------------------------------------ points
@dataclass(frozen=True)
class RunData:
    """The scalar content of a run file (frames stay on disk until asked for).

    Arrays have one row per stored point (completion order); angles in degrees. The
    ``frame_*`` arrays have one entry per stored frame.
    """

    path: Path
    run_id: str
    plan_kind: str
    plan_name: str
    sample_name: str
    status: str
    index: np.ndarray
    label: np.ndarray
    point_status: np.ndarray
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_r: np.ndarray
    phi_r: np.ndarray
    exposure_us: np.ndarray
    power_w: np.ndarray
    signal: np.ndarray
    n_frames: np.ndarray
    frame_start: np.ndarray
    positions: np.ndarray
    axes: tuple[str, ...]
    frame_point: np.ndarray
    frame_exposure_us: np.ndarray
    frame_light: np.ndarray
    acquisition: dict[str, Any]
    geometry: dict[str, Any]
    profile_text: str
    plan_text: str
    calibration: dict[str, str]
    identities: dict[str, dict[str, str]] = field(default_factory=dict)
    frame_saturated: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    frame_shape: tuple[int, ...] | None = None
    #: :data:`~instrument.run.layout.DETECTOR_FIELDS` columns the file has, also readable
    #: as attributes (``run.lockin_r_v``; ``None`` for a file without them).
    #: ``filter_position`` is an integer slot (-1: none), ``lockin_overload`` 0 or 1,
    #: ``nd_position`` the neutral-density filter's slot (-1: open beam; None for a file
    #: written before the engine used ND filters: every reading was of the open beam).
    detectors: dict[str, np.ndarray] = field(default_factory=dict)

    def __getattr__(self, name: str) -> Any:
        if name in DETECTOR_FIELDS:
            return self.__dict__.get("detectors", {}).get(name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def n_points(self) -> int:
        return int(self.index.size)

    def position(self, role: str) -> np.ndarray:
        """Read-back positions of ``role`` per point (NaN if the run did not move it)."""
        if role not in self.axes:
            return np.full(self.n_points, np.nan)
        return self.positions[:, self.axes.index(role)]

    def brdf_rows(self) -> np.ndarray:
        """Rows that are measured scattering points: status ok, finite angles."""
        ok = (self.point_status == 0) & np.isfinite(self.theta_i) & np.isfinite(self.theta_r)
        return np.flatnonzero(ok & np.isin(self.label, ["sample", "reference", "signature"]))

    def profile(self) -> dict[str, Any]:
        """The bench profile stored with the run (parsed TOML; empty if none)."""
        return tomllib.loads(self.profile_text) if self.profile_text else {}

    def plan(self) -> PlanSpec:
        """The plan stored with the run, validated as a plan file is."""
        return parse_plan(self.plan_text, source=f"plan stored in {self.path}")

    def camera_calibration(self, calibration_file: str | Path | None = None
                           ) -> CameraCalibration:
        """The camera's radiometric calibration for this run
        (:func:`instrument.bench.camera_calibration.camera_calibration_for`)."""
        return camera_calibration_for(
            self.profile(), calibration_file=calibration_file,
            stored_file=self.calibration.get("camera_calibration"),
            gain_db=self.camera_gain() or 0.0,
            pixel_format=self.identities.get("camera", {}).get("pixel_format"))

    def camera_gain(self) -> float | None:
        """The camera's gain as the run started (attribute ``gain`` of
        ``/entry/instrument/camera``, the device's units); None where the run file does
        not record it."""
        text = self.identities.get("camera", {}).get("gain")
        try:
            return None if text is None else float(text)
        except ValueError:
            return None

    @contextlib.contextmanager
    def frames(self) -> Iterator[h5py.Dataset]:
        """The frame stack ``(n_frames, H, W)`` on disk, open for reading while in the block."""
        with open_run(self.path) as f:
            if "frames" not in f["entry/data"]:
                raise RunFileError(f"{self.path} holds no frames")
            yield f["entry/data/frames"]

    def frames_of(self, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(light frames (N, H, W), exposures (N,), dark frames (N, H, W) or None) of a row.

        Darks are matched to brackets by exposure: the point's own dark frames first,
        then dark-labelled points of the run (``dark = "start"``).
        """
        n0, n = int(self.frame_start[row]), int(self.n_frames[row])
        if n == 0:
            raise ValueError(f"point {self.index[row]} has no frames")
        with self.frames() as ds:
            stack = np.asarray(ds[n0:n0 + n], dtype=np.float64)
            light = self.frame_light[n0:n0 + n].astype(bool)
            exp = self.frame_exposure_us[n0:n0 + n]
            lf, le = stack[light], exp[light]
            darks: list[np.ndarray] = []
            pool = list(zip(exp[~light], stack[~light], strict=True))
            for e in le:
                k = next((j for j, (de, _) in enumerate(pool) if math.isclose(de, e)), None)
                if k is None:
                    d = self._run_dark(ds, float(e))
                    if d is None:
                        return lf, le, None
                    darks.append(d)
                else:
                    darks.append(pool.pop(k)[1])
        return lf, le, np.array(darks)

    def _run_dark(self, frames: h5py.Dataset, exposure_us: float) -> np.ndarray | None:
        for r in np.flatnonzero((self.label == "dark") & (self.point_status == STATUS_OK)):
            n0, n = int(self.frame_start[r]), int(self.n_frames[r])
            for j in range(n0, n0 + n):
                if math.isclose(float(self.frame_exposure_us[j]), exposure_us):
                    return np.asarray(frames[j], dtype=np.float64)
        return None


def read_plan_kind(path: str | Path) -> str:
    """The plan kind a run file records (``brdf_in_plane``, ``lightfield`` …), read alone so
    that an analysis can refuse a run of another kind before it reads anything else."""
    with open_run(path) as f:
        if "entry" not in f:
            raise RunFileError(f"{path} is an HDF5 file but not a scatterlab run file (no "
                               "/entry with a run id)")
        return as_text(f["entry"].attrs.get("plan_kind", ""))


def read_run(path: str | Path) -> RunData:
    """Read a run file's scalar tables and metadata (plain h5py, read-only).

    Raises
    ------
    RunFileError
        A group or table of the layout is missing (it names which).
    """
    path = Path(path)
    with open_run(path) as f:
        try:
            return _read_run(path, f)
        except KeyError as err:
            raise RunFileError(f"{path} is not a complete scatterlab run file: "
                               f"{err.args[0] if err.args else err}") from None


def _read_run(path: Path, f: h5py.File) -> RunData:
    e = f["entry"]
    p = e["points"]
    d = e["data"]
    inst = e["instrument"]
    geometry = {k.split(".", 1)[1]: (v.item() if hasattr(v, "item") else v)
                for k, v in inst.attrs.items() if k.startswith("geometry.")}
    identities = {name: {k: as_text(v) for k, v in g.attrs.items()}
                  for name, g in inst.items() if isinstance(g, h5py.Group)}
    axes = tuple(as_text(a) for a in e["plan/axes"][()])
    cal = {k: as_text(v) for k, v in e["calibration"].attrs.items() if k != "NX_class"}
    frames = d.get("frames")

    def col(name: str, grp: h5py.Group = p) -> np.ndarray:
        return np.asarray(grp[name][()])

    detectors = {name: col(name) for name in DETECTOR_FIELDS if name in p}
    for name, missing in (("filter_position", -1), ("lockin_overload", 0), ("nd_position", -1)):
        if name in detectors:
            v = detectors[name]
            detectors[name] = np.where(np.isfinite(v), v, missing).astype(np.int64)

    return RunData(
        path=path,
        run_id=as_text(e.attrs.get("run_id", path.stem)),
        plan_kind=as_text(e.attrs.get("plan_kind", "")),
        plan_name=as_text(e.attrs.get("plan_name", "")),
        sample_name=as_text(e["sample/name"][()]) if "sample/name" in e else "",
        status=as_text(e.attrs.get("status", "")),
        index=col("index"),
        label=np.array([as_text(x) for x in p["label"][()]]),
        point_status=col("status"),
        theta_i=col("theta_i"), phi_i=col("phi_i"),
        theta_r=col("theta_r"), phi_r=col("phi_r"),
        exposure_us=col("exposure_us"), power_w=col("power_w"), signal=col("signal"),
        n_frames=col("n_frames"), frame_start=col("frame_start"),
        positions=col("positions"), axes=axes,
        frame_point=col("frame_point", d), frame_exposure_us=col("frame_exposure_us", d),
        frame_light=col("frame_light", d),
        acquisition=json.loads(as_text(e["plan/acquisition_policy"][()])),
        geometry=geometry,
        profile_text=as_text(inst["bench_profile"][()]),
        plan_text=as_text(e["plan/plan_text"][()]),
        calibration=cal,
        identities=identities,
        frame_saturated=col("frame_saturated", d),
        frame_shape=None if frames is None else tuple(frames.shape[1:]),
        detectors=detectors,
    )


# ------------------------------------------------------------------------------ plan
@dataclass(frozen=True)
class PlannedPoints:
    """The plan's points as the run stored them (every planned point, in order; an
    adaptive run's grew during the run).

    ``targets`` (n, len(axes)) and ``angles`` (n, 4: θi, φi, θr, φr) hold NaN where a point
    has no target on an axis or no scattering geometry; ``exposure_us`` NaN where the
    policy chooses the exposure.
    """

    plan_text: str
    axes: tuple[str, ...]
    targets: np.ndarray
    angles: np.ndarray
    label: tuple[str, ...]
    light: np.ndarray
    exposure_us: np.ndarray
    #: Per point, its meta as JSON (empty for files written before it).
    meta: tuple[str, ...] = ()
    #: An adaptive run's plan as JSON (:attr:`RunSummary.adaptive`); "" for a fixed plan.
    adaptive: str = ""


def read_planned(path: str | Path) -> PlannedPoints:
    """The planned points stored in a run file (what ``resume`` continues)."""
    with open_run(path) as f:
        p = f["entry/plan"]
        return PlannedPoints(
            as_text(p["plan_text"][()]),
            tuple(as_text(a) for a in p["axes"][()]),
            p["planned_targets"][()], p["planned_angles"][()],
            tuple(as_text(s) for s in p["planned_label"][()]),
            p["planned_light"][()], p["planned_exposure_us"][()],
            tuple(as_text(x) for x in p["planned_meta"][()]) if "planned_meta" in p else (),
            as_text(p.attrs.get("adaptive", "")))


# ------------------------------------------------------------------------------ summary
@dataclass(frozen=True)
class RunSummary:
    """What a run file holds, in a few numbers (read without loading any table)."""

    path: Path
    run_id: str
    plan_kind: str
    status: str
    n_points: int
    n_planned: int
    n_frames: int
    n_skipped: int
    frame_shape: tuple[int, ...] | None
    size_bytes: int
    sample_name: str = ""
    axes: tuple[str, ...] = ()
    #: What the bench recorded per point, in words ("angles", "exposures", "power
    #: readings", "signals", "timestamps"): only the columns that hold a value somewhere.
    recorded: tuple[str, ...] = ()
    #: Points whose frames a damaged file lost (status 2), not measured again yet.
    lost: tuple[int, ...] = ()
    #: An adaptive run's plan as JSON (name, parameters, seed; its planned table grew
    #: during the run, ADR 0091); empty for a fixed plan and in older files.
    adaptive: str = ""


#: Point columns and their names in a summary, in the order they are listed.
_RECORDED = (("theta_r", "angles"), ("exposure_us", "exposures"),
             ("power_w", "power readings"), ("signal", "signals"), ("t_end", "timestamps"))


def read_summary(path: str | Path) -> RunSummary:
    """What a (closed) run file holds, read with plain h5py."""
    path = Path(path)
    with open_run(path) as f:
        e = f["entry"]
        frames = e["data"].get("frames")
        status = e["points/status"][:]
        recorded = tuple(words for name, words in _RECORDED
                         if name in e["points"] and np.isfinite(e["points"][name][()]).any())
        lost = tuple(int(i) for i in e["points/index"][()][status == FRAMES_LOST])
        return RunSummary(path, as_text(e.attrs["run_id"]), as_text(e.attrs["plan_kind"]),
                          as_text(e.attrs["status"]), int(e["points/index"].shape[0]),
                          int(e.attrs["n_planned"]),
                          0 if frames is None else int(frames.shape[0]),
                          int((status == STATUS_SKIPPED).sum()),
                          None if frames is None else tuple(frames.shape[1:]),
                          path.stat().st_size,
                          as_text(e["sample/name"][()]) if "sample/name" in e else "",
                          tuple(as_text(a) for a in e["plan/axes"][()]), recorded, lost,
                          as_text(e["plan"].attrs.get("adaptive", "")))


# ------------------------------------------------------------------------------ log
def read_events(path: str | Path) -> list[dict[str, Any]]:
    """The run's event log, oldest first: one dict per ``/entry/events/log`` line as the
    engine wrote it (``kind`` — fault, paused, resumed, skipped … —, ``time`` in seconds
    since the epoch, and the kind's fields: a fault has ``device``, ``cause``, ``action``
    and ``index``). Lines that are not JSON objects are returned as ``{"kind": "text",
    "text": line}`` rather than dropped."""
    with h5py.File(path, "r") as f:
        log = f.get("entry/events/log")
        lines = [] if log is None else [as_text(x) for x in log[()]]
    out: list[dict[str, Any]] = []
    for line in lines:
        try:
            rec = json.loads(line)
        except ValueError:
            rec = None
        out.append(rec if isinstance(rec, dict) else {"kind": "text", "text": line})
    return out


def read_attributes(path: str | Path) -> dict[str, str]:
    """The run's provenance attributes on ``/entry`` (run id, plan kind and name, status,
    software version, start and end time, durability …) as text."""
    with h5py.File(path, "r") as f:
        if "entry" not in f:
            raise RunFileError(f"{path} is not a scatterlab run file (no /entry group)")
        attrs = dict(f["entry"].attrs.items())
        attrs.update(f.attrs.items())
    return {k: as_text(v) if isinstance(v, bytes | str) else str(v) for k, v in attrs.items()}
