"""The run file's layout: what is where, and how an empty run file is made.

Layout (``/entry`` is an NXentry; every group carries an ``NX_class`` attribute)::

    /entry                      attrs: run_id, plan_kind, plan_name, status, start_time,
                                end_time, software_version, schema_version, durability
      sample/      NXsample     name, description
      instrument/  NXinstrument bench_profile (TOML text), geometry attrs,
                                <role>/ (NXpositioner | NXdetector | NXsource | NXmonitor)
                                with the device identity and retry policy as attributes
                                (a camera's also its gain and pixel_format at the start);
                                optical_train (JSON, a polarimetric run only: the
                                profile's nominal [optics] and the plan's [polarimetry];
                                the mounts' read-back angles are columns of positions)
      plan/        NXcollection plan_text, acquisition_policy, retry_policies (JSON),
                                axes, planned_targets (N, A), planned_angles (N, 4),
                                planned_label, planned_light, planned_exposure_us;
                                attr ``adaptive`` (JSON) on an adaptive run, whose
                                planned tables are extendible and grow (ADR 0091)
      calibration/ NXcollection one attribute per calibration reference (run id or path)
      points/      NXcollection per completed point (row = order of first completion; a
                                point measured again keeps its row): index, label, status
                                (0 ok, 1 skipped, 2 frames lost to a damaged file), note,
                                t_start, t_end (Unix s), positions (N, A) read back,
                                theta_i, phi_i, theta_r, phi_r (deg, from the read-back
                                positions), exposure_us, power_w, signal, n_frames,
                                frame_start, retries
      data/        NXdata       frames (F, H, W) chunked per frame, compressed when it
                                pays; frame_point (-1: a lost measurement's frames, since
                                measured again), frame_exposure_us, frame_light,
                                frame_timestamp, frame_saturated; signal/axes linked from
                                points/
      events/      NXcollection log: one JSON string per event (faults, pauses, resumes,
                                repairs of the file)

Tables grow one row per point; their chunks hold ``table_chunk_rows(n_planned)`` rows, so a
short run does not carry a 1024-row chunk per table. :func:`new_run_file` makes the empty
layout from a :class:`RunHeader` (the run's creation and a rebuild from its journal use the
same code); :func:`header_from_file` reads the header back from a run file whose journal is
gone; :func:`end_of_allocation` reads how much of the file HDF5 uses, so the space reserved
for writes that never came can be given back.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

__all__ = [
    "DETECTOR_FIELDS",
    "FRAMES_LOST",
    "FRAMES_LOST_NOTE",
    "PEM_FIELDS",
    "REMEASURED_NOTE",
    "STATUS_OK",
    "STATUS_SKIPPED",
    "RunHeader",
    "StorageError",
    "detector_columns",
    "end_of_allocation",
    "grow_plan_tables",
    "header_from_file",
    "journal_path",
    "new_run_file",
    "table_chunk_rows",
]

SCHEMA_VERSION = 1
FLOAT_FIELDS = ("t_start", "t_end", "theta_i", "phi_i", "theta_r", "phi_r", "exposure_us",
                "power_w", "signal")
INT_FIELDS = ("index", "status", "n_frames", "frame_start", "retries")
STR_FIELDS = ("label", "note")
#: A PEM polarimeter's per-point readings (ADR 0106): the DC on Aux In 1, the in-phase 1f
#: and 2f (signed V rms) with their σ, Y, phase θ and full scale, the settle in time
#: constants, and the modulator's amplitude (rad at its wavelength setting, nm) and
#: frequency (Hz).
PEM_FIELDS = ("pem_dc_v", "pem_u_dc_v", "pem_1f_v", "pem_u_1f_v", "pem_1f_y_v",
              "pem_1f_theta_deg", "pem_1f_sensitivity_v", "pem_2f_v", "pem_u_2f_v",
              "pem_2f_y_v", "pem_2f_theta_deg", "pem_2f_sensitivity_v",
              "pem_time_constants", "pem_amplitude_rad", "pem_wavelength_nm",
              "pem_frequency_hz")
#: Per-point readings of the optional detectors and of the light's band, NaN where the bench
#: has no such device (and in files written before they existed: readers must not require
#: them): the lock-in's mean R over the point's readings and its standard error (V rms), X,
#: Y (V), θ (deg), its full-scale range (V rms) and time constant (s) at the reading, 1 if
#: it overloaded; the filter in the beam (slot, centre wavelength and FWHM in nm); with
#: ``dark = "per_point"``, the point's dark readings (light off: shutter closed or source
#: off): the power meter's (W) and the lock-in's mean X, Y (V) and the standard error of
#: one component (V rms); the slot of the neutral-density filter the camera read the point
#: through when it clipped at its shortest exposure (NaN: open beam); a PEM polarimeter's
#: point adds :data:`PEM_FIELDS`.
DETECTOR_FIELDS = ("lockin_r_v", "lockin_u_r_v", "lockin_x_v", "lockin_y_v",
                   "lockin_theta_deg", "lockin_sensitivity_v", "lockin_time_constant_s",
                   "lockin_overload", "filter_position", "wavelength_nm", "bandwidth_nm",
                   "power_dark_w", "lockin_dark_x_v", "lockin_dark_y_v", "lockin_dark_u_v",
                   "nd_position", *PEM_FIELDS)
FRAME_FIELDS = ("frame_point", "frame_exposure_us", "frame_light", "frame_timestamp",
                "frame_saturated")
STATUS_OK, STATUS_SKIPPED = 0, 1
#: A committed point whose frames a damaged file no longer holds (stored as zeros):
#: its scalar values (from the journal) stand, its frames must not be analysed.
FRAMES_LOST = 2
FRAMES_LOST_NOTE = "frames lost: the run file was damaged; scalars recovered from the journal"
#: The note of a point measured again after its first measurement's frames were lost.
REMEASURED_NOTE = "re-measured: the frames of its first measurement were lost to a damaged file"
#: Rows per chunk of the per-point tables at most (long runs), and frames per point assumed
#: when sizing the per-frame tables' chunks.
MAX_CHUNK_ROWS = 1024
FRAMES_PER_POINT_GUESS = 2
_STR = h5py.string_dtype()


class StorageError(OSError):
    """A run file could not be written (disk full, I/O error) or is not a run file.

    ``clean`` is true when the error was detected before anything was written (free-space
    check, space reservation): the file is then intact and can be closed normally.
    """

    clean = False


def clean_error(code: int, message: str) -> StorageError:
    err = StorageError(code, message)
    err.clean = True
    return err


@dataclass(frozen=True)
class RunHeader:
    """Everything written once, at creation; also the journal's first record."""

    run_id: str
    plan_kind: str
    plan_name: str
    plan_text: str
    profile_text: str
    bench_name: str
    sample_name: str
    sample_description: str
    axes: tuple[str, ...]
    planned_targets: list[list[float]]
    planned_angles: list[list[float]]
    planned_label: list[str]
    planned_light: list[bool]
    planned_exposure_us: list[float]
    acquisition_policy: str
    retry_policies: str
    identities: dict[str, dict[str, str]]
    device_kinds: dict[str, str]
    geometry: dict[str, Any]
    calibration: dict[str, str]
    software_version: str
    created: float
    #: Per planned point, what else it carries (``ScanPoint.meta`` as JSON ``[[key,
    #: value], …]``: the filter slot of a wavelength axis), so that a resumed run acquires
    #: each point as planned; empty in files written before it (points without meta).
    planned_meta: list[str] = field(default_factory=list)
    #: An adaptive run's plan (:mod:`instrument.plans.adaptive`): JSON of its name,
    #: parameters and seed, from which a resumed run rebuilds it; empty for a fixed plan.
    #: Its planned tables grow during the run (:func:`grow_plan_tables`, ADR 0091).
    adaptive: str = ""
    #: A polarimetric run's optical train and scan: JSON ``{"optics": the profile's
    #: nominal [optics], "polarimetry": the plan's [polarimetry]}``; empty otherwise.
    optical_train: str = ""

    def with_planned(self, rows: list[dict[str, Any]]) -> RunHeader:
        """This header with ``rows`` (a journal ``planned`` record's points) appended to
        its planned points."""
        n = len(self.planned_label)
        meta = list(self.planned_meta)
        if meta or any(r.get("meta") for r in rows):
            meta = (meta or ["[]"] * n) + [json.dumps(r.get("meta", [])) for r in rows]
        return replace(
            self,
            planned_targets=[*self.planned_targets, *(list(r["targets"]) for r in rows)],
            planned_angles=[*self.planned_angles, *(list(r["angles"]) for r in rows)],
            planned_label=[*self.planned_label, *(str(r["label"]) for r in rows)],
            planned_light=[*self.planned_light, *(bool(r["light"]) for r in rows)],
            planned_exposure_us=[*self.planned_exposure_us,
                                 *(float(r["exposure_us"]) for r in rows)],
            planned_meta=meta)

    def as_dict(self) -> dict[str, Any]:
        d = dict(vars(self))
        d["axes"] = list(self.axes)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunHeader:
        d = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        d["axes"] = tuple(d["axes"])
        return cls(**d)


def journal_path(path: str | Path) -> Path:
    return Path(str(path) + ".journal")


def iso_time(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t)) + f"{t % 1:.3f}"[1:]


def _group(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    g = parent.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def table_chunk_rows(n_rows: int) -> int:
    """Rows per chunk of a growing table expected to reach ``n_rows`` rows: all of them in
    one chunk up to ``MAX_CHUNK_ROWS`` (a chunk is allocated whole, so a fixed 1024-row
    chunk made a 17-point run file mostly empty space), at least 8."""
    return int(min(MAX_CHUNK_ROWS, max(8, n_rows)))


def _ext(grp: h5py.Group, name: str, dtype: Any, *, chunk: int, width: int | None = None,
         units: str | None = None) -> h5py.Dataset:
    shape, maxshape, chunks = (0,), (None,), (chunk,)
    if width is not None:
        shape, maxshape, chunks = (0, max(width, 1)), (None, max(width, 1)), (chunk, max(width, 1))
    d = grp.create_dataset(name, shape=shape, maxshape=maxshape, chunks=chunks, dtype=dtype)
    if units:
        d.attrs["units"] = units
    return d


#: Units of the per-point columns (stored as each dataset's ``units`` attribute).
UNITS = {"t_start": "s", "t_end": "s", "theta_i": "deg", "phi_i": "deg", "theta_r": "deg",
          "phi_r": "deg", "exposure_us": "us", "power_w": "W", "signal": "DN/us",
          "lockin_r_v": "V", "lockin_u_r_v": "V", "lockin_x_v": "V", "lockin_y_v": "V",
          "lockin_theta_deg": "deg", "lockin_sensitivity_v": "V",
          "lockin_time_constant_s": "s", "wavelength_nm": "nm", "bandwidth_nm": "nm",
          "power_dark_w": "W", "lockin_dark_x_v": "V", "lockin_dark_y_v": "V",
          "lockin_dark_u_v": "V", **{name: "V" for name in PEM_FIELDS if name.endswith("_v")},
          "pem_1f_theta_deg": "deg", "pem_2f_theta_deg": "deg", "pem_amplitude_rad": "rad",
          "pem_wavelength_nm": "nm", "pem_frequency_hz": "Hz"}


def new_run_file(path: Path, h: RunHeader) -> h5py.File:
    """An empty run file with the layout of the module docstring (open for writing)."""
    f = h5py.File(path, "w")
    try:
        f.attrs["default"] = "entry"
        f.attrs["creator"] = "scatterlab"
        entry = _group(f, "entry", "NXentry")
        entry.attrs["default"] = "data"
        for key in ("run_id", "plan_kind", "plan_name", "software_version"):
            entry.attrs[key] = getattr(h, key)
        entry.attrs["schema_version"] = SCHEMA_VERSION
        entry.attrs["status"] = "running"
        entry.attrs["start_time"] = iso_time(h.created)
        entry.attrs["n_planned"] = len(h.planned_label)
        entry.attrs["n_points"] = 0
        entry.create_dataset("title", data=h.plan_name)
        sample = _group(entry, "sample", "NXsample")
        sample.create_dataset("name", data=h.sample_name)
        sample.create_dataset("description", data=h.sample_description)
        inst = _group(entry, "instrument", "NXinstrument")
        inst.create_dataset("name", data=h.bench_name)
        inst.create_dataset("bench_profile", data=h.profile_text)
        if h.optical_train:
            inst.create_dataset("optical_train", data=h.optical_train)
        for k, v in h.geometry.items():
            if isinstance(v, str | int | float | bool):
                inst.attrs[f"geometry.{k}"] = v
        retry = json.loads(h.retry_policies)
        for role, kind in h.device_kinds.items():
            g = _group(inst, role, kind)
            for k, v in h.identities.get(role, {}).items():
                g.attrs[k] = str(v)
            if role in retry:
                g.attrs["retry_policy"] = json.dumps(retry[role])
        plan = _group(entry, "plan", "NXcollection")
        plan.create_dataset("plan_text", data=h.plan_text)
        plan.create_dataset("acquisition_policy", data=h.acquisition_policy)
        plan.create_dataset("retry_policies", data=h.retry_policies)
        plan.create_dataset("axes", data=np.array(list(h.axes), dtype=object), dtype=_STR)
        if h.adaptive:
            plan.attrs["adaptive"] = h.adaptive
        write_plan_tables(plan, h)
        cal = _group(entry, "calibration", "NXcollection")
        for k, v in h.calibration.items():
            cal.attrs[k] = v
        n = len(h.planned_label)
        rows = table_chunk_rows(n)
        pts = _group(entry, "points", "NXcollection")
        for name in (*FLOAT_FIELDS, *DETECTOR_FIELDS):
            _ext(pts, name, "f8", chunk=rows, units=UNITS.get(name))
        for name in INT_FIELDS:
            _ext(pts, name, "i8", chunk=rows)
        for name in STR_FIELDS:
            _ext(pts, name, _STR, chunk=rows)
        _ext(pts, "positions", "f8", chunk=rows, width=len(h.axes))
        pts["positions"].attrs["axes"] = ",".join(h.axes)
        data = _group(entry, "data", "NXdata")
        for name, dt in zip(FRAME_FIELDS, ("i8", "f8", "bool", "f8", "f8"), strict=True):
            _ext(data, name, dt, chunk=table_chunk_rows(FRAMES_PER_POINT_GUESS * n))
        data["signal"] = pts["signal"]
        for name in ("theta_i", "theta_r", "phi_r"):
            data[name] = pts[name]
        data.attrs["signal"] = "signal"
        data.attrs["axes"] = ["theta_r"]
        ev = _group(entry, "events", "NXcollection")
        _ext(ev, "log", _STR, chunk=64)
    except BaseException:
        f.close()
        raise
    return f


def _plan_columns(h: RunHeader) -> dict[str, np.ndarray]:
    n = len(h.planned_label)
    cols = {
        "planned_targets": np.array(h.planned_targets, dtype=float).reshape(n, len(h.axes)),
        "planned_angles": np.array(h.planned_angles, dtype=float).reshape(n, 4),
        "planned_label": np.array(h.planned_label, dtype=object),
        "planned_light": np.array(h.planned_light, dtype=bool),
        "planned_exposure_us": np.array(h.planned_exposure_us, dtype=float),
    }
    if h.planned_meta:
        cols["planned_meta"] = np.array(h.planned_meta, dtype=object)
    return cols


def write_plan_tables(plan: h5py.Group, h: RunHeader) -> None:
    """Create the planned-point tables of a new file. A fixed plan's are written once, at
    their size; an adaptive plan's (``h.adaptive``) can grow (:func:`grow_plan_tables`)."""
    for name, data in _plan_columns(h).items():
        kw: dict[str, Any] = {"dtype": _STR} if data.dtype == object else {}
        if h.adaptive:
            kw.update(maxshape=(None, *data.shape[1:]),
                      chunks=(64, *(max(d, 1) for d in data.shape[1:])))
        plan.create_dataset(name, data=data, **kw)


def grow_plan_tables(plan: h5py.Group, h: RunHeader) -> bool:
    """Make the planned-point tables of an adaptive run's file hold ``h``'s planned points
    (the journal's, which may be more than the file holds after a crash); returns whether
    anything was written. Rows the file has beyond ``h`` were never committed and go."""
    n = len(h.planned_label)
    changed = False
    for name, data in _plan_columns(h).items():
        if name not in plan:  # the first point with meta: the column starts now
            plan.create_dataset(name, data=data, dtype=_STR, maxshape=(None,), chunks=(64,))
            changed = True
            continue
        d = plan[name]
        have = d.shape[0]
        if have == n:
            continue
        d.resize(n, axis=0)
        if n > have:
            d[have:n] = data[have:n]
        changed = True
    plan.parent.attrs["n_planned"] = n
    return changed


def detector_columns(grp: h5py.Group, extras: list[dict[str, float]]
                     ) -> dict[str, list[float]]:
    """The :data:`DETECTOR_FIELDS` columns of rows whose readings are ``extras``, for the
    columns the points table ``grp`` has (a file of an older layout has none)."""
    return {name: [float(e.get(name, math.nan)) for e in extras]
            for name in DETECTOR_FIELDS if name in grp}


def put_rows(grp: h5py.Group, n0: int, n1: int, cols: dict[str, list[Any]],
             pos: np.ndarray, *, shrink: bool = True) -> None:
    """Write rows ``n0:n1`` of the points table; the table is resized to ``n1`` rows (grown
    only, without ``shrink``, when rows in the middle are rewritten)."""
    for name, vals in cols.items():
        d = grp[name]
        if d.shape[0] < n1 or (shrink and d.shape[0] != n1):
            d.resize(n1, axis=0)
        if n1 > n0:
            d[n0:n1] = vals
    d = grp["positions"]
    if d.shape[0] < n1 or (shrink and d.shape[0] != n1):
        d.resize(n1, axis=0)
    if n1 > n0:
        d[n0:n1] = pos




def _text(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _parse_iso(text: str) -> float:
    """Seconds since the epoch from :func:`iso_time` text (local time)."""
    whole, _, frac = text.partition(".")
    t = time.mktime(time.strptime(whole, "%Y-%m-%dT%H:%M:%S"))
    return t + (float("0." + frac) if frac.isdigit() else 0.0)


def header_from_file(f: h5py.File) -> RunHeader:
    """The :class:`RunHeader` a run file was created from, read back from the file itself
    (for a run whose journal is lost). Raises ``KeyError`` naming a missing part."""
    e = f["entry"]
    plan = e["plan"]
    inst = e["instrument"]
    retry = json.loads(_text(plan["retry_policies"][()]))
    identities: dict[str, dict[str, str]] = {}
    kinds: dict[str, str] = {}
    for role, g in inst.items():
        if not isinstance(g, h5py.Group):
            continue
        kinds[role] = _text(g.attrs.get("NX_class", "NXcollection"))
        identities[role] = {k: _text(v) for k, v in g.attrs.items()
                            if k not in ("NX_class", "retry_policy")}
    geometry = {k.split(".", 1)[1]: (v.item() if hasattr(v, "item") else v)
                for k, v in inst.attrs.items() if k.startswith("geometry.")}
    return RunHeader(
        run_id=_text(e.attrs["run_id"]), plan_kind=_text(e.attrs["plan_kind"]),
        plan_name=_text(e.attrs.get("plan_name", "")),
        plan_text=_text(plan["plan_text"][()]),
        profile_text=_text(inst["bench_profile"][()]),
        bench_name=_text(inst["name"][()]) if "name" in inst else "",
        sample_name=_text(e["sample/name"][()]) if "sample/name" in e else "",
        sample_description=(_text(e["sample/description"][()])
                            if "sample/description" in e else ""),
        axes=tuple(_text(a) for a in plan["axes"][()]),
        planned_targets=plan["planned_targets"][()].tolist(),
        planned_angles=plan["planned_angles"][()].tolist(),
        planned_label=[_text(s) for s in plan["planned_label"][()]],
        planned_light=[bool(x) for x in plan["planned_light"][()]],
        planned_exposure_us=[float(x) for x in plan["planned_exposure_us"][()]],
        planned_meta=([_text(x) for x in plan["planned_meta"][()]]
                      if "planned_meta" in plan else []),
        adaptive=_text(plan.attrs.get("adaptive", "")),
        optical_train=(_text(inst["optical_train"][()]) if "optical_train" in inst else ""),
        acquisition_policy=_text(plan["acquisition_policy"][()]),
        retry_policies=json.dumps(retry), identities=identities, device_kinds=kinds,
        geometry=geometry,
        calibration={k: _text(v) for k, v in e["calibration"].attrs.items()
                     if k != "NX_class"},
        software_version=_text(e.attrs.get("software_version", "")),
        created=_parse_iso(_text(e.attrs.get("start_time", "1970-01-01T00:00:00"))))


#: The HDF5 file signature (HDF5 File Format Specification 3.0, §II.A, "Format Signature").
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def end_of_allocation(path: str | Path) -> int | None:
    """Bytes of ``path`` that HDF5 has allocated (its superblock's base address plus
    "End of File Address"), or None when the superblock is not one this reads.

    Superblock layouts after the HDF5 File Format Specification 3.0, §II.A: versions 0
    and 1 hold the size of offsets at byte 13 and the base, free-space, end-of-file and
    driver-block addresses from byte 24 (version 0) or 28 (version 1); versions 2 and 3
    hold the size of offsets at byte 9 and the base, superblock-extension and end-of-file
    addresses from byte 12. The superblock of a file without a user block is at byte 0.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return None
    if len(head) < 32 or head[:8] != HDF5_SIGNATURE:
        return None
    version = head[8]
    if version in (0, 1):
        size, start = head[13], (24 if version == 0 else 28)
        fields = (0, 2)  # base address, end-of-file address (after the free-space one)
    elif version in (2, 3):
        size, start = head[9], 12
        fields = (0, 2)  # base address, end-of-file address (after the extension one)
    else:
        return None
    if size not in (2, 4, 8) or start + 3 * size > len(head):
        return None
    base, eof = (int.from_bytes(head[start + k * size:start + (k + 1) * size], "little")
                 for k in fields)
    return base + eof
