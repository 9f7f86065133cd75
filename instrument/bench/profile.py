"""Bench profiles: which devices a bench has, where they are, and what they may do.

A profile is a TOML file. It is untrusted input: :func:`load_profile` validates every
field and reports *all* problems at once in a :class:`ProfileError`, each naming the
field path (``devices.sample_theta.limits``) and what to do. Nothing is opened or moved
before a profile has validated.

Schema (all lengths in mm, angles in degrees)::

    [bench]
    name = "sim"                       # required
    description = "..."

    [devices.<role>]                   # one table per device; the key is its role
    driver = "thorlabs_apt"            # a registered driver: scatterlab devices
                                       # --list-drivers (instrument.bench.driver_registry)
    url = "simapt://sample_theta?model=K10CR1"   # device path or pyserial/sim URL
    serial = "40123456"                # instead of url, for a driver that finds its device
                                       # by serial number (basler)
    stage = "K10CR1"                   # motion drivers: stage model
    limits = [-90.0, 90.0]             # motion: soft limits in axis units
    velocity = 10.0                    # motion: units/s (written to the controller)
    acceleration = 20.0                # motion: units/s²
    position_tolerance = 0.01          # motion: arrival tolerance in axis units
    readback_resolution = 7.3e-6       # motion: read-back quantum (axis units; default
                                       # from the driver's stage, instrument.bench.angles)
    repeatability = 0.005              # motion: ± bidirectional repeatability (axis
                                       # units; emulated stages 0, else not known)
    settle_s = 0.01                    # motion: settling after each move (planning, s)
    relative_noise = 0.001             # power meter: 1σ noise of a reading as a fraction
                                       # of it (instrument.bench.meter_noise)
    noise_floor_w = 2.6e-10            # power meter: 1σ of a dark reading (W), used when
                                       # the run's darks are too few to measure it
    home_s = 20.0                      # motion: time homing takes (estimates, s)
    frame_overhead_s = 0.02            # camera: time per frame beyond the exposure (s)
    scene_change_s = 0.1               # camera: extra time of the first frame after a
                                       # move or the light turned on (s); both for
                                       # duration estimates (instrument.bench.timing)
    options = { ... }                  # driver-specific keyword arguments (the keys
                                       # the driver's registration declares)
    settings = { ... }                 # public properties set after opening (the
                                       # driver's declared settings, e.g. wavelength_nm)

    [devices.<role>.retry]             # recovery policy for this device (optional)
    attempts = 3                       # tries of an idempotent operation
    backoff_s = 0.1                    # first back-off, doubled each try
    on_failure = "pause"               # "pause" | "skip" | "rehome" | "abort"

    [geometry]                         # goniometer geometry
    goniometer = "type_ii"             # "type_ii": fixed source, the sample rotates, the
                                       # detector orbits (default); "type_i": source and
                                       # detector arms over a stationary sample (ADR 0099)
    kind = "in_plane"                  # "in_plane" | "out_of_plane" (type_i: out_of_plane)
    detector_distance_mm = 300.0       # sample centre to detector aperture
    detector_aperture_mm = 5.0         # diameter of the detector's limiting aperture
    min_bistatic_deg = 6.0             # detector must stay this far from the beam
    source_theta_deg = 0.0             # fixed source direction in the lab frame

    [geometry.source_arm]              # type_i only: the source's arc and azimuth stages
    radius_mm = 400.0                  # sample centre to the source head (arc radius)
    width_mm = 40.0                    # width of the arm's head across the arc
    arc_offset_deg = 0.0               # source_arc reading with the source at the pole
    azimuth_offset_deg = 0.0           # source_azimuth reading at sample azimuth 0

    [geometry.detector_arm]            # type_i only; its radius is detector_distance_mm
    width_mm = 14.0
    arc_offset_deg = 0.0
    azimuth_offset_deg = 0.0
    field_of_view_deg = 0.0            # full angle of the detector's view cone beyond
                                       # its aperture (0: it sees the sample centre only)

    [[geometry.collision]]             # arm-collision zones (any number; optional)
    axis = "detector_theta"            # an axis role
    range = [150.0, 180.0]             # forbidden interval of that axis (or of the difference)
    relative_to = "sample_theta"       # optional: the zone applies to axis − relative_to
    reason = "arm hits the sample holder"

    [source]                           # the light source (optional)
    coherence = "incoherent"           # "laser" | "incoherent" (default): a laser on a
                                       # rough sample makes speckle, which the reduction
                                       # counts in each value's σ (docs/guide, speckle)
    wavelength_nm = 633.0              # a laser's wavelength (the speckle grain); on an
                                       # emulated bench [simulation.source]'s by default
    [[optics.source]]                  # a polarimeter's optical train (optional):
    kind = "retarder"                  # polarisers, retarders and PEMs in each arm, with
    mount = "psg_retarder"             # their mounts and nominal values; see
    retardance_deg = 90.0              # instrument.bench.optics

    [simulation]                       # only for emulated benches; passed to hw_mocks
    world = "sim"
    ...
"""

from __future__ import annotations

import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from instrument.bench.driver_registry import DriverEntry, driver_registry
from instrument.bench.optics import OpticalTrain, parse_optics

__all__ = [
    "AXIS_ROLES",
    "GONIOMETER_TYPES",
    "SPIN_ROLE",
    "ArmSpec",
    "BenchProfile",
    "CollisionZone",
    "DeviceSpec",
    "FieldError",
    "GeometrySpec",
    "ProfileError",
    "RetryPolicy",
    "load_profile",
    "parse_profile",
]

#: Roles of motion axes the kinematics and plans know about.
AXIS_ROLES = (
    "sample_theta",
    "sample_phi",
    "sample_tilt",
    "detector_theta",
    "detector_phi",
    "source_theta",
    "camera_z",
    # the arms of a type (i) goniometer (instrument.bench.kinematics.TypeIKinematics)
    "source_arc",
    "source_azimuth",
    "detector_arc",
    "detector_azimuth",
    # rotation mounts of a polarimeter's elements ([optics], instrument.bench.optics)
    "psg_polariser",
    "psg_retarder",
    "psa_retarder",
    "psa_polariser",
)
#: ``geometry.goniometer``: the two designs (ADR 0099).
GONIOMETER_TYPES = ("type_ii", "type_i")

#: The role of a sample spinner: a continuous-rotation stage turning the sample about its
#: normal while the camera exposes, to average a laser's speckle (ADR 0098). Not an axis
#: of the kinematics: plans never position it, the engine spins it (``spin_deg_s``).
SPIN_ROLE = "sample_spin"
#: ``[photodiode]``: the chopped photodiode a lock-in reads (its transimpedance amplifier
#: and chopper), key → (low, high); ``responsivity_a_per_w`` may be a table over
#: ``responsivity_nm``.
PHOTODIODE_KEYS = {
    "responsivity_a_per_w": (1e-6, 10.0), "u_responsivity_rel": (0.0, 1.0),
    "transimpedance_v_per_a": (1.0, 1e12), "u_transimpedance_rel": (0.0, 1.0),
    "aperture_diameter_mm": (0.01, 1000.0), "distance_mm": (1.0, 1e5),
    "chopper_hz": (0.01, 1e5),
}
#: A serial number: letters, digits and inner dashes (Basler: 8 digits; its camera
#: emulation: ``0815-0000``), for a driver that finds its device by one (``by_serial``).
SERIAL_PATTERN = re.compile(r"[A-Za-z0-9]+(-[A-Za-z0-9]+)*")
#: Camera timing keys (seconds, for duration estimates) and their upper bound.
CAMERA_TIMING = {"frame_overhead_s": 60.0, "scene_change_s": 600.0}
ON_FAILURE = ("pause", "skip", "rehome", "abort")


@dataclass(frozen=True)
class FieldError:
    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


class ProfileError(ValueError):
    """A profile or plan failed validation; ``errors`` lists every offending field."""

    def __init__(self, source: str, errors: list[FieldError]) -> None:
        self.source = source
        self.errors = list(errors)
        lines = "\n".join(f"  - {e}" for e in self.errors)
        super().__init__(f"{source} is not valid ({len(self.errors)} problem(s)):\n{lines}")


@dataclass(frozen=True)
class RetryPolicy:
    """What the engine does when an operation on this device fails."""

    attempts: int = 3
    backoff_s: float = 0.1
    on_failure: str = "pause"

    def as_dict(self) -> dict[str, Any]:
        return {"attempts": self.attempts, "backoff_s": self.backoff_s,
                "on_failure": self.on_failure}


@dataclass(frozen=True)
class DeviceSpec:
    role: str
    driver: str
    url: str
    stage: str | None = None
    limits: tuple[float, float] | None = None
    velocity: float | None = None
    acceleration: float | None = None
    position_tolerance: float | None = None
    options: dict[str, Any] = field(default_factory=dict)
    retry: RetryPolicy = field(default_factory=RetryPolicy)
    settle_s: float = 0.0
    #: Measurement settings applied after opening, through the device's validated public
    #: properties (e.g. a power meter's ``wavelength_nm``), as its driver declares them.
    settings: dict[str, Any] = field(default_factory=dict)
    #: Cameras: seconds per frame beyond the exposure, and extra seconds of the first
    #: frame after the scene changed (estimates only; :mod:`instrument.bench.timing`).
    frame_overhead_s: float = 0.0
    scene_change_s: float = 0.0
    #: Motion: seconds homing takes on the real stage (estimates only).
    home_s: float = 0.0
    #: The timing keys the profile gave (the others are defaults: estimates say so).
    timing_declared: frozenset[str] = frozenset()

    @property
    def kind(self) -> str | None:
        """The device kind of the driver (``"motion_axis"``...;
        :data:`~instrument.bench.driver_registry.KINDS`), None for a driver that is not
        registered."""
        return driver_registry().kind_of(self.driver)

    @property
    def is_axis(self) -> bool:
        return self.kind == "motion_axis"

    @property
    def is_simulated(self) -> bool:
        return self.url.startswith("sim")


@dataclass(frozen=True)
class CollisionZone:
    """A forbidden interval of one axis (or of ``axis − relative_to``), in axis units."""

    axis: str
    low: float
    high: float
    relative_to: str | None = None
    reason: str = "arm collision"

    def hit(self, positions: dict[str, float]) -> bool:
        if self.axis not in positions:
            return False
        value = positions[self.axis]
        if self.relative_to is not None:
            if self.relative_to not in positions:
                return False
            value -= positions[self.relative_to]
        return self.low <= value <= self.high

    def describe(self) -> str:
        what = self.axis if self.relative_to is None else f"{self.axis} - {self.relative_to}"
        return f"{what} in [{self.low:g}, {self.high:g}] ({self.reason})"


@dataclass(frozen=True)
class ArmSpec:
    """One arm of a type (i) goniometer (ADR 0099): its head (the source or the detector
    on its carriage) at ``radius_mm`` from the sample centre, ``width_mm`` wide across the
    arc; the stage readings at the pole (arc) and at sample azimuth 0 (azimuth); for the
    detector, the full angle of its view cone beyond the aperture."""

    radius_mm: float
    width_mm: float
    arc_offset_deg: float = 0.0
    azimuth_offset_deg: float = 0.0
    field_of_view_deg: float = 0.0

    @property
    def half_width_deg(self) -> float:
        """Angular half-width of the head seen from the sample centre, degrees."""
        return math.degrees(math.atan2(self.width_mm / 2.0, self.radius_mm))


@dataclass(frozen=True)
class GeometrySpec:
    """The goniometer's geometry. The optional beam and sample entries describe what each
    reading integrates (the instrument function of the BRDF fit,
    :mod:`analysis.brdf.reduction.receiver`): the beam's 1/e² radius at the sample and its
    divergence (1/e² half-angle), and the sample's radius (it clips the footprint at
    grazing incidence). ``None``: not declared (a simulated bench takes them from its
    source and scene)."""

    kind: str = "in_plane"
    detector_distance_mm: float = 300.0
    detector_aperture_mm: float = 5.0
    min_bistatic_deg: float = 6.0
    source_theta_deg: float = 0.0
    collisions: tuple[CollisionZone, ...] = ()
    beam_radius_mm: float | None = None
    beam_divergence_mrad: float | None = None
    sample_radius_mm: float | None = None
    goniometer: str = "type_ii"
    source_arm: ArmSpec | None = None
    detector_arm: ArmSpec | None = None

    @property
    def is_type_i(self) -> bool:
        return self.goniometer == "type_i"

    @property
    def reaches_hemisphere(self) -> bool:
        """Whether the bench reaches directions off the plane of incidence."""
        return self.is_type_i or self.kind == "out_of_plane"

    @property
    def detector_solid_angle_sr(self) -> float:
        """Solid angle of the circular detector aperture seen from the sample centre.

        Exact cone form Ω = 2π(1 − cos α) with tan α = (D/2)/R, not the small-angle A/R².
        """
        half = math.atan2(self.detector_aperture_mm / 2.0, self.detector_distance_mm)
        return 2.0 * math.pi * (1.0 - math.cos(half))


@dataclass(frozen=True)
class BenchProfile:
    name: str
    description: str
    devices: dict[str, DeviceSpec]
    geometry: GeometrySpec
    simulation: dict[str, Any] | None
    source_text: str  # the TOML as read, stored with every run for provenance
    #: ``[photodiode]`` as validated (plain data; the lock-in reduction reads it from the
    #: profile stored with each run), or None.
    photodiode: dict[str, Any] | None = None
    #: ``[source]`` as validated: ``coherence`` ("laser" or "incoherent") and, where
    #: given, ``wavelength_nm`` (:func:`_source`).
    source: dict[str, Any] = field(default_factory=lambda: {"coherence": "incoherent"})

    @property
    def coherence(self) -> str:
        """``"laser"`` or ``"incoherent"``: the source's coherence."""
        return str(self.source["coherence"])

    #: ``[optics]``: a polarimeter's elements and their nominal values, or None.
    optics: OpticalTrain | None = None

    @property
    def axes(self) -> dict[str, DeviceSpec]:
        return {role: d for role, d in self.devices.items() if d.is_axis}

    def device(self, role: str) -> DeviceSpec:
        try:
            return self.devices[role]
        except KeyError:
            raise KeyError(f"bench {self.name!r} has no device with role {role!r}; "
                           f"it has {sorted(self.devices)}") from None


# --------------------------------------------------------------------------- loading


#: Former names of built-in profiles, still accepted (run files and scripts name them):
#: the built-in names are written with hyphens.
PROFILE_ALIASES = {"sim_out_of_plane": "sim-out-of-plane"}


def builtin_profiles() -> list[str]:
    """Names of the profiles shipped with scatterlab (``sim``...)."""
    folder = resources.files("instrument.bench") / "profiles"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def canonical_bench_name(name: str) -> str:
    """A bench's current name (``sim_out_of_plane`` → ``sim-out-of-plane``)."""
    return PROFILE_ALIASES.get(name, name)


def same_bench(a: str, b: str) -> bool:
    """Whether two recorded bench names name the same bench (aliases included)."""
    return canonical_bench_name(a) == canonical_bench_name(b)


def load_profile(name_or_path: str | Path) -> BenchProfile:
    """Load a built-in profile by name, or a profile file by path."""
    text_path = Path(name_or_path)
    if text_path.suffix == ".toml" or text_path.exists():
        try:
            text = text_path.read_text(encoding="utf-8")
        except OSError as err:
            raise ProfileError(str(text_path), [FieldError("file", f"cannot read: {err}")]
                               ) from err
        return parse_profile(text, source=str(text_path))
    name = canonical_bench_name(str(name_or_path))
    if name not in builtin_profiles():
        raise ProfileError(name, [FieldError(
            "bench", f"no built-in profile {name!r} and no such file; built-in profiles: "
            f"{', '.join(builtin_profiles())}")])
    text = (resources.files("instrument.bench") / "profiles" / f"{name}.toml").read_text("utf-8")
    return parse_profile(text, source=f"built-in profile {name!r}")


def parse_profile(text: str, *, source: str = "profile") -> BenchProfile:
    """Validate TOML ``text`` into a :class:`BenchProfile` or raise :class:`ProfileError`."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ProfileError(source, [FieldError("toml", f"not valid TOML: {err}")]) from err
    v = _Validator()
    bench = v.table(data, "bench", required=True)
    name = v.string(bench, "name", "bench", required=True) or ""
    description = v.string(bench, "description", "bench") or ""
    v.unknown(bench, "bench", {"name", "description"})

    devices: dict[str, DeviceSpec] = {}
    device_tables = v.table(data, "devices", required=True)
    if not device_tables and "devices" in data:
        v.error("devices", "at least one device is needed")
    for role, table in device_tables.items():
        path = f"devices.{role}"
        if not isinstance(table, dict):
            v.error(path, "must be a table")
            continue
        spec = _device(v, role, table, path)
        if spec is not None:
            devices[role] = spec
    geometry = _geometry(v, v.table(data, "geometry"), "geometry")
    simulation = data.get("simulation")
    if simulation is not None and not isinstance(simulation, dict):
        v.error("simulation", "must be a table")
        simulation = None
    photodiode = _photodiode(v, data.get("photodiode"))
    if photodiode is not None and not any(d.kind == "lockin" for d in devices.values()):
        v.error("photodiode", "describes the lock-in's detector: the bench needs a device "
                "with driver 'sr830' (or another driver of kind 'lockin')")
    light = _source(v, data.get("source"), simulation)
    optics = None
    if "optics" in data:
        axes = {role for role, d in devices.items() if d.is_axis}
        optics = parse_optics(data["optics"], axes, v.error)
    v.unknown(data, "", {"bench", "devices", "geometry", "simulation", "photodiode",
                         "source", "optics"})
    if v.errors:
        raise ProfileError(source, v.errors)
    return BenchProfile(name, description, devices, geometry, simulation, text, photodiode,
                        light, optics)



#: What ``[source] coherence`` may say.
COHERENCE = ("incoherent", "laser")


def _source(v: _Validator, t: Any, simulation: dict[str, Any] | None) -> dict[str, Any]:
    """``[source]``: the coherence of the light and a laser's wavelength. On an emulated
    bench the simulated source follows it; a ``[simulation.source] coherence`` that says
    otherwise is refused (one bench, one source)."""
    out: dict[str, Any] = {"coherence": "incoherent"}
    if t is None:
        t = {}
    if not isinstance(t, dict):
        v.error("source", "must be a table")
        return out
    coherence = t.get("coherence", "incoherent")
    if coherence not in COHERENCE:
        v.error("source.coherence", f"must be one of {', '.join(repr(c) for c in COHERENCE)} "
                f"(a laser speckles on a rough sample; a lamp does not), got {coherence!r}")
    else:
        out["coherence"] = coherence
    wavelength = v.positive(t, "wavelength_nm", "source")
    if wavelength is not None:
        out["wavelength_nm"] = wavelength
    v.unknown(t, "source", {"coherence", "wavelength_nm"})
    sim_source = (simulation or {}).get("source")
    if isinstance(sim_source, dict) and "coherence" in sim_source \
            and sim_source["coherence"] != out["coherence"]:
        v.error("simulation.source.coherence", f"says {sim_source['coherence']!r} but "
                f"[source] coherence is {out['coherence']!r}: set it once, in [source]")
    return out


def _photodiode(v: _Validator, t: Any) -> dict[str, Any] | None:
    """``[photodiode]`` (:data:`PHOTODIODE_KEYS`): every number finite and in range; a
    responsivity table needs ``responsivity_nm`` of the same length, increasing."""
    if t is None:
        return None
    if not isinstance(t, dict):
        v.error("photodiode", "must be a table")
        return None
    v.unknown(t, "photodiode", {*PHOTODIODE_KEYS, "responsivity_nm"})
    for key in ("responsivity_a_per_w", "transimpedance_v_per_a"):
        if key not in t:
            v.error(f"photodiode.{key}", "is required")
    out: dict[str, Any] = {}
    for key, (low, high) in PHOTODIODE_KEYS.items():
        if key not in t:
            continue
        raw = t[key]
        values = raw if key == "responsivity_a_per_w" and isinstance(raw, list) else [raw]
        if not values or not all(_is_number(x) and low <= x <= high for x in values):
            what = "numbers" if len(values) > 1 else "a number"
            v.error(f"photodiode.{key}", f"must be {what} from {low:g} to {high:g}")
            continue
        out[key] = [float(x) for x in raw] if isinstance(raw, list) else float(raw)
    resp = out.get("responsivity_a_per_w")
    if isinstance(resp, list):
        nm = t.get("responsivity_nm")
        if (not isinstance(nm, list) or len(nm) != len(resp)
                or not all(_is_number(x) and 100 <= x <= 25000 for x in nm)
                or any(b <= a for a, b in itertools.pairwise(nm))):
            v.error("photodiode.responsivity_nm", f"must list {len(resp)} increasing "
                    "wavelengths in nm (100 to 25000), one per responsivity value")
        else:
            out["responsivity_nm"] = [float(x) for x in nm]
    elif "responsivity_nm" in t:
        v.error("photodiode.responsivity_nm", "goes with a table of responsivities only")
    return out


def _device(v: _Validator, role: str, t: dict[str, Any], path: str) -> DeviceSpec | None:
    known = {"driver", "url", "serial", "stage", "limits", "velocity", "acceleration",
             "position_tolerance", "options", "retry", "settle_s", "settings",
             "home_s", "readback_resolution", "repeatability", "relative_noise",
             "noise_floor_w", *CAMERA_TIMING}
    v.unknown(t, path, known)
    driver = v.string(t, "driver", path, required=True)
    registry = driver_registry()
    entry = None
    if driver is not None:
        found = registry.get(driver)
        if found is None:
            v.error(f"{path}.driver", registry.unknown_driver_message(driver))
            driver = None
        else:
            entry = found.entry
    kind = None if entry is None else entry.kind
    if entry is not None and entry.by_serial:
        url = _serial(v, t, path, driver)
    else:
        url = v.string(t, "url", path, required=True)
        if url is not None and not url.strip():
            v.error(f"{path}.url", "must not be empty")
        if "serial" in t and entry is not None:
            v.error(f"{path}.serial", f"driver {driver!r} finds its device by its url; only "
                    f"drivers that find theirs by serial number "
                    f"({', '.join(registry.serial_drivers()) or 'none'}) take 'serial'")
    is_axis = kind == "motion_axis"
    if is_axis and role not in (*AXIS_ROLES, SPIN_ROLE):
        v.error(path, f"motion driver on unknown role {role!r}; axis roles are "
                f"{', '.join(AXIS_ROLES)} (and {SPIN_ROLE}, a sample spinner)")
    stage = v.string(t, "stage", path)
    limits = None
    if "limits" in t:
        raw = t["limits"]
        if (not isinstance(raw, list) or len(raw) != 2
                or not all(_is_number(x) for x in raw)):
            v.error(f"{path}.limits", "must be [low, high], two numbers")
        elif not (math.isfinite(raw[0]) and math.isfinite(raw[1]) and raw[0] < raw[1]):
            v.error(f"{path}.limits", f"need finite low < high, got {raw}")
        else:
            limits = (float(raw[0]), float(raw[1]))
    if not is_axis:
        for key in ("limits", "velocity", "acceleration", "position_tolerance", "stage",
                    "settle_s", "home_s", "readback_resolution", "repeatability"):
            if key in t and driver is not None:
                v.error(f"{path}.{key}", f"only motion devices take {key!r}")
    velocity = v.positive(t, "velocity", path)
    acceleration = v.positive(t, "acceleration", path)
    tolerance = v.positive(t, "position_tolerance", path)
    # the angular error model of the recorded angles (instrument.bench.angles)
    v.positive(t, "readback_resolution", path)
    if "repeatability" in t and not (_is_number(t["repeatability"])
                                     and 0 <= t["repeatability"] < math.inf):
        v.error(f"{path}.repeatability", "must be a number ≥ 0 (± half-width, axis units)")
    # the power meter's noise per reading (instrument.bench.meter_noise)
    for key, what in (("relative_noise", "a fraction of a reading from 0 to 1 (1σ, e.g. "
                                         "0.001)"),
                      ("noise_floor_w", "a power in W from 0 to 1 (1σ of a dark reading)")):
        if key not in t:
            continue
        if kind is not None and kind != "power_meter":
            v.error(f"{path}.{key}", f"only power meters take {key!r}")
        elif not (_is_number(t[key]) and 0 <= t[key] < 1):
            v.error(f"{path}.{key}", f"must be {what}")
    options = _declared(v, t.get("options", {}), entry, driver, "options", f"{path}.options")
    retry = _retry(v, t.get("retry", {}), f"{path}.retry")
    settle = t.get("settle_s", 0.0)
    if not _is_number(settle) or not 0 <= settle <= 10:
        v.error(f"{path}.settle_s", "must be a number of seconds from 0 to 10")
        settle = 0.0
    settings = _declared(v, t.get("settings", {}), entry, driver, "settings",
                         f"{path}.settings")
    timing = {}
    home = t.get("home_s", 0.0)
    if not _is_number(home) or not 0 <= home <= 600:
        v.error(f"{path}.home_s", "must be a number of seconds from 0 to 600")
    elif is_axis:
        timing["home_s"] = float(home)
    for key, high in CAMERA_TIMING.items():
        if key not in t:
            continue
        if kind is not None and kind != "camera":
            v.error(f"{path}.{key}", f"only cameras take {key!r}")
        elif not _is_number(t[key]) or not 0 <= t[key] <= high:
            v.error(f"{path}.{key}", f"must be a number of seconds from 0 to {high:g}")
        else:
            timing[key] = float(t[key])
    if driver is None or url is None:
        return None
    return DeviceSpec(role, driver, url, stage, limits, velocity, acceleration, tolerance,
                      dict(options), retry, float(settle), settings, **timing,
                      timing_declared=frozenset(timing))


def _serial(v: _Validator, t: dict[str, Any], path: str, driver: str | None) -> str | None:
    """The ``serial`` of a device its driver finds by serial number (it stands in for the
    url)."""
    if "url" in t:
        v.error(f"{path}.url", f"driver {driver!r} finds its device by serial number: give "
                "serial = \"...\" (on its label, or from scatterlab devices) instead")
    serial = v.string(t, "serial", path, required=True)
    if serial is not None and not SERIAL_PATTERN.fullmatch(serial):
        v.error(f"{path}.serial", f"{serial!r} is not a serial number (letters, digits and "
                "inner dashes, as on the device's label)")
        return None
    return serial


def _declared(v: _Validator, t: Any, entry: DriverEntry | None, driver: str | None,
              table: str, path: str) -> dict[str, Any]:
    """A device's ``options`` or ``settings`` table, each key checked against what its
    driver's registration declares (:class:`~instrument.bench.driver_registry.Option`)."""
    if not isinstance(t, dict):
        v.error(path, "must be a table")
        return {}
    if entry is None:  # an unknown driver, already reported
        return dict(t)
    allowed = entry.options if table == "options" else entry.settings
    out: dict[str, Any] = {}
    for key, value in t.items():
        option = allowed.get(key)
        if option is None:
            names = ", ".join(sorted(allowed)) or "none"
            v.error(f"{path}.{key}", f"not {'an option' if table == 'options' else 'a setting'}"
                    f" of driver {driver!r} ({table}: {names})")
            continue
        problem = option.problem(value)
        if problem is not None:
            v.error(f"{path}.{key}", problem)
            continue
        out[key] = option.convert(value)
    return out


def _retry(v: _Validator, t: Any, path: str) -> RetryPolicy:
    if not isinstance(t, dict):
        v.error(path, "must be a table")
        return RetryPolicy()
    v.unknown(t, path, {"attempts", "backoff_s", "on_failure"})
    attempts = t.get("attempts", 3)
    if not isinstance(attempts, int) or isinstance(attempts, bool) or not 1 <= attempts <= 20:
        v.error(f"{path}.attempts", "must be an integer from 1 to 20")
        attempts = 3
    backoff = t.get("backoff_s", 0.1)
    if not _is_number(backoff) or not 0 <= backoff <= 60:
        v.error(f"{path}.backoff_s", "must be a number of seconds from 0 to 60")
        backoff = 0.1
    on_failure = t.get("on_failure", "pause")
    if on_failure not in ON_FAILURE:
        v.error(f"{path}.on_failure", f"must be one of {', '.join(ON_FAILURE)}")
        on_failure = "pause"
    return RetryPolicy(int(attempts), float(backoff), str(on_failure))


def _geometry(v: _Validator, t: dict[str, Any], path: str) -> GeometrySpec:
    v.unknown(t, path, {"kind", "detector_distance_mm", "detector_aperture_mm",
                        "min_bistatic_deg", "source_theta_deg", "collision",
                        "beam_radius_mm", "beam_divergence_mrad", "sample_radius_mm",
                        "goniometer", "source_arm", "detector_arm"})
    default = GeometrySpec()
    goniometer = v.string(t, "goniometer", path) or default.goniometer
    if goniometer not in GONIOMETER_TYPES:
        v.error(f"{path}.goniometer", "must be 'type_ii' (fixed source, rotating sample) or "
                "'type_i' (source and detector arms over a stationary sample)")
        goniometer = default.goniometer
    kind = v.string(t, "kind", path) or (
        "out_of_plane" if goniometer == "type_i" else default.kind)
    if kind not in ("in_plane", "out_of_plane"):
        v.error(f"{path}.kind", "must be 'in_plane' or 'out_of_plane'")
        kind = default.kind
    if goniometer == "type_i" and kind != "out_of_plane":
        v.error(f"{path}.kind", "a type_i goniometer's arms reach the hemisphere: leave "
                "kind out or set it to 'out_of_plane'")
        kind = "out_of_plane"
    distance = v.positive(t, "detector_distance_mm", path) or default.detector_distance_mm
    aperture = v.positive(t, "detector_aperture_mm", path) or default.detector_aperture_mm
    if aperture >= 2 * distance:
        v.error(f"{path}.detector_aperture_mm", "must be smaller than twice the distance")
    bistatic = t.get("min_bistatic_deg", default.min_bistatic_deg)
    if not _is_number(bistatic) or not 0 <= bistatic < 90:
        v.error(f"{path}.min_bistatic_deg", "must be a number of degrees in [0, 90)")
        bistatic = default.min_bistatic_deg
    source = t.get("source_theta_deg", default.source_theta_deg)
    if not _is_number(source) or not -180 <= source <= 180:
        v.error(f"{path}.source_theta_deg", "must be a number of degrees in [-180, 180]")
        source = default.source_theta_deg
    collisions = _collisions(v, t.get("collision", []), f"{path}.collision")
    divergence = t.get("beam_divergence_mrad")
    if divergence is not None and (not _is_number(divergence) or divergence < 0):
        v.error(f"{path}.beam_divergence_mrad", f"must be a number >= 0, got {divergence!r}")
        divergence = None
    arms = _arms(v, t, path, goniometer, float(distance))
    return GeometrySpec(kind, float(distance), float(aperture), float(bistatic), float(source),
                        collisions, beam_radius_mm=v.positive(t, "beam_radius_mm", path),
                        beam_divergence_mrad=(None if divergence is None
                                              else float(divergence)),
                        sample_radius_mm=v.positive(t, "sample_radius_mm", path),
                        goniometer=goniometer, source_arm=arms[0], detector_arm=arms[1])


#: Keys of ``[geometry.source_arm]`` / ``[geometry.detector_arm]`` → (low, high); the
#: detector arm's radius is ``detector_distance_mm`` and only it has a field of view.
ARM_KEYS = {"radius_mm": (1.0, 1e5), "width_mm": (0.0, 1e4),
            "arc_offset_deg": (-360.0, 360.0), "azimuth_offset_deg": (-360.0, 360.0),
            "field_of_view_deg": (0.0, 90.0)}


def _arms(v: _Validator, t: dict[str, Any], path: str, goniometer: str, distance: float
          ) -> tuple[ArmSpec | None, ArmSpec | None]:
    """``source_arm`` and ``detector_arm`` of a type (i) goniometer (both required there,
    refused on a type (ii)); every number finite and in :data:`ARM_KEYS`' range."""
    out: list[ArmSpec | None] = []
    for name in ("source_arm", "detector_arm"):
        where = f"{path}.{name}"
        raw = t.get(name)
        if goniometer != "type_i":
            if raw is not None:
                v.error(where, "only a type_i goniometer has arms (set "
                        f"{path}.goniometer = 'type_i', or remove this table)")
            out.append(None)
            continue
        if not isinstance(raw, dict):
            v.error(where, "is required for a type_i goniometer: a table with width_mm"
                    + (" and radius_mm" if name == "source_arm" else ""))
            out.append(None)
            continue
        known = {k for k in ARM_KEYS
                 if (k != "radius_mm" or name == "source_arm")
                 and (k != "field_of_view_deg" or name == "detector_arm")}
        v.unknown(raw, where, known)
        values: dict[str, float] = {}
        for key in sorted(known):
            low, high = ARM_KEYS[key]
            if key not in raw:
                if key in ("radius_mm", "width_mm"):
                    v.error(f"{where}.{key}", "is required")
                continue
            x = raw[key]
            if not _is_number(x) or not low <= x <= high or (key == "width_mm" and x <= 0):
                v.error(f"{where}.{key}", f"must be a number from {low:g} to {high:g}"
                        + (" (> 0)" if key == "width_mm" else "") + f", got {x!r}")
                continue
            values[key] = float(x)
        if name == "detector_arm":
            values["radius_mm"] = distance
        if "radius_mm" in values and "width_mm" in values:
            if values["width_mm"] >= 2 * values["radius_mm"]:
                v.error(f"{where}.width_mm", "must be smaller than twice the arm's radius")
                out.append(None)
                continue
            out.append(ArmSpec(**values))
        else:
            out.append(None)
    return out[0], out[1]


def _collisions(v: _Validator, raw: Any, path: str) -> tuple[CollisionZone, ...]:
    if not isinstance(raw, list):
        v.error(path, "must be an array of tables ([[geometry.collision]])")
        return ()
    zones = []
    for i, t in enumerate(raw):
        where = f"{path}[{i}]"
        if not isinstance(t, dict):
            v.error(where, "must be a table")
            continue
        v.unknown(t, where, {"axis", "range", "relative_to", "reason"})
        axis = v.string(t, "axis", where, required=True)
        if axis is not None and axis not in AXIS_ROLES:
            v.error(f"{where}.axis", f"must be an axis role: {', '.join(AXIS_ROLES)}")
            axis = None
        rel = v.string(t, "relative_to", where)
        if rel is not None and rel not in AXIS_ROLES:
            v.error(f"{where}.relative_to", f"must be an axis role: {', '.join(AXIS_ROLES)}")
            rel = None
        reason = v.string(t, "reason", where) or "arm collision"
        rng = t.get("range")
        if (not isinstance(rng, list) or len(rng) != 2
                or not all(_is_number(x) for x in rng) or not rng[0] < rng[1]):
            v.error(f"{where}.range", "must be [low, high], two finite numbers with low < high")
            continue
        if axis is not None:
            zones.append(CollisionZone(axis, float(rng[0]), float(rng[1]), rel, reason))
    return tuple(zones)


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


class _Validator:
    """Collects field errors instead of stopping at the first."""

    def __init__(self) -> None:
        self.errors: list[FieldError] = []

    def error(self, path: str, message: str) -> None:
        self.errors.append(FieldError(path or "(top level)", message))

    def table(self, data: dict[str, Any], key: str, *, required: bool = False) -> dict[str, Any]:
        if key not in data:
            if required:
                self.error(key, "missing table")
            return {}
        value = data[key]
        if not isinstance(value, dict):
            self.error(key, "must be a table")
            return {}
        return value

    def string(self, t: dict[str, Any], key: str, path: str, *,
               required: bool = False) -> str | None:
        if key not in t:
            if required:
                self.error(f"{path}.{key}", "is required")
            return None
        value = t[key]
        if not isinstance(value, str):
            self.error(f"{path}.{key}", f"must be a string, got {type(value).__name__}")
            return None
        return value

    def positive(self, t: dict[str, Any], key: str, path: str) -> float | None:
        if key not in t:
            return None
        value = t[key]
        if not _is_number(value) or value <= 0:
            self.error(f"{path}.{key}", f"must be a finite number > 0, got {value!r}")
            return None
        return float(value)

    def unknown(self, t: dict[str, Any], path: str, known: set[str]) -> None:
        for key in t:
            if key not in known:
                where = f"{path}.{key}" if path else key
                self.error(where, f"unknown field; expected one of {', '.join(sorted(known))}")
