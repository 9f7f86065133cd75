"""How long things take on this bench: what the profile says about its clocks and camera.

The planner's motion model (:mod:`instrument.bench.dynamics`) gives the time a move takes
on the real stage. A bench may not run in real time: an emulated controller
(``simapt://``, ``simsmc://``, any ``sim…://`` URL) runs its motion on a clock ``speed``
times faster than the wall clock (the ``speed=`` option of its URL, hw_mocks/clock.py
``ScaledClock``; ``step=`` advances the clock at every reading, so a move takes no wall
time to speak of, taken here as a speed-up of 10⁹), and the
simulated camera takes no wall time to expose unless its URL says ``realtime=1``. A camera
also costs time beyond the exposure: per frame (``frame_overhead_s``: readout and transfer
on a real camera; synthesising the sensor noise on the simulated one) and once after each
change of the scene (``scene_change_s``: the first frame after a move or after the light
came on, when a real camera's queue is flushed and the simulated one renders the new
view; a simulated light-field wall adds its render cost per view, ``render_s``, from the
scene's walls and objects: :mod:`instrument.bench.render_cost`). Homing an axis takes
``home_s`` of its own time (the profile says how long; an emulated axis takes that divided
by its speed-up). :func:`bench_timing` collects these from
a profile so that an estimate says what *this* bench will take.

No cost counts as zero because a profile left it out: a camera without
``frame_overhead_s`` or ``scene_change_s`` takes its driver's default
(:data:`CAMERA_DEFAULTS`) and the estimate says which it assumed (a plugin's camera, which
has none, is taken as zero, and the estimate says to give them). A lock-in waits its
output filter's 99 % settling time (τ from the profile's settings, else the SR830's
power-up 100 ms; the slope's wait in time constants from the driver's table,
:attr:`drivers.base.LockIn.SETTLE_TIME_CONSTANTS`) once per snapshot and twice more to
choose its range. A filter wheel turns the shorter way round at the FW102C's high speed,
half a turn in 3 s, and settles on the slot sensor for 0.1 s (Thorlabs FW102C manual,
as the emulator models it: hw_mocks/firmware/fw102c.py); twice as long at its normal speed
(``wheel_speed=0``), and an emulated wheel's clock ``speed=`` times faster. The engine's
neutral-density turns near a specular peak are predicted by the plan
(:meth:`instrument.plans.build.Plan.estimate`).

An emulated power meter or lock-in on the simulated goniometer bench (a ``simusb://`` or
``simsr830://`` URL with ``world=``) integrates the scattered light over its aperture
once per world state it is read in (a move, the light switched, a filter turned;
``hw_mocks.sim.goniometer_scene.GoniometerScene.power_on_aperture``): the power meter one
integral, the lock-in's photodiode two with the light on (the light as it is, and the
ambient part the chopper does not modulate) and one with it off. A real detector has no
such cost, but the simulated bench's wall clock does, like the simulated camera's render:
:data:`SIM_APERTURE_INTEGRAL_S` (CPU seconds measured on the project's dev box,
``benchmarks/bench_estimate_parts.py``: a shared box stretches wall time with its load,
not CPU time), for the lit integral in proportion to the nodes of the emulator's rule
over the aperture (the scene's ``aperture_samples``, :func:`aperture_nodes`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

from drivers.base import LockIn
from instrument.bench.profile import BenchProfile, DeviceSpec
from instrument.bench.render_cost import lightfield_render_s

__all__ = ["CAMERA_DEFAULTS", "POINT_OVERHEAD_S", "SIM_APERTURE_INTEGRAL_S",
           "SIM_APERTURE_SAMPLES", "BenchTiming", "aperture_nodes", "bench_timing",
           "clock_speed", "exposes_in_wall_time"]

#: A camera's costs when the profile does not give them, by driver: seconds per frame
#: beyond the exposure and seconds of the first frame after the scene changed. The
#: simulated camera's are those measured for the sim profile (1024² px: synthesising the
#: noise, rendering the view through the pupil); a USB camera's one frame period at
#: 30 frames/s, and two after a change (its queue flushed).
CAMERA_DEFAULTS: dict[str, dict[str, float]] = {
    "sim_camera": {"frame_overhead_s": 0.055, "scene_change_s": 0.32},
    "opencv_camera": {"frame_overhead_s": 1 / 30, "scene_change_s": 2 / 30},
    # a GenICam camera, software-triggered: one frame period at 50 frames/s (the transfer
    # of a few-megapixel Mono12 frame over USB3); nothing stale to flush after a change
    "basler": {"frame_overhead_s": 1 / 50, "scene_change_s": 0.0},
}
#: CPU seconds of one scattered-light integral over an emulated detector's aperture on the
#: simulated goniometer bench, (light on, light off), by the scene's ``brdf`` (the
#: wavelength-dependent sample evaluates its albedo table and Fresnel factor per sample
#: point; off, only the ambient term is left). The power meter's head and the lock-in's
#: photodiode integrate over the same aperture with the same function. Measured with
#: ``benchmarks/bench_estimate_parts.py`` (examples/brdf_inplane.toml on ``sim``,
#: examples/brdf_spectral_lockin.toml on ``sim-spectral``; BENCHMARKS.md, honest_sigma).
SIM_APERTURE_INTEGRAL_S: dict[str, tuple[float, float]] = {
    "spectral": (0.093, 0.0003),
    "default": (0.030, 0.0003),
}
#: The scene's ``aperture_samples`` those costs were measured at (the emulator's default).
#: A lit integral's cost grows with the rule's nodes (:func:`aperture_nodes`): measured
#: CPU per integral on sim-spectral 4.3× and 9.5× the default's at 144 and 324 nodes (4×
#: and 9× the nodes), on sim 5.8× and 15× (BENCHMARKS.md, honest4); the estimate scales
#: the lit cost by the node count.
SIM_APERTURE_SAMPLES = 9
#: The SR830's output filter at power-up (time constant, slope): 100 ms, 12 dB/oct.
LOCKIN_POWER_UP = (0.1, 12)
#: FW102C at high speed: seconds per degree of the wheel's turn, settling on the slot.
WHEEL_S_PER_DEG = 3.0 / 180.0
WHEEL_SETTLE_S = 0.1

#: The simulated camera's sensor width when its URL does not give one (hw_mocks' default).
SIM_CAMERA_WIDTH = 1024

#: The speed-up taken for an emulator clock that steps per reading (``step=``).
STEPPING_SPEEDUP = 1e9

#: Seconds the engine and the storage add per point with frames: the HDF5 flush and the
#: two fsyncs (file and journal) that make the point durable, the status polls that end
#: the move, the hand-over to the writer thread. Measured on the project's dev box
#: (points of examples/lightfield_scan.toml, whose camera costs ~1 ms): 10–14 ms.
POINT_OVERHEAD_S = 0.012


def _query(url: str) -> dict[str, str]:
    return {k: v[-1] for k, v in parse_qs(urlsplit(url).query).items()}


def clock_speed(spec: DeviceSpec) -> float:
    """How many times faster than the wall clock the device's motion runs: the ``speed=``
    option of an emulated controller's URL (default 1), 1 for real hardware."""
    scheme = urlsplit(spec.url).scheme
    if not scheme.startswith("sim") or scheme in ("simcam", "simsource", "simusb"):
        return 1.0
    query = _query(spec.url)
    if "step" in query:
        return STEPPING_SPEEDUP
    try:
        speed = float(query.get("speed", 1.0))
    except ValueError:
        return 1.0
    return speed if 0 < speed < float("inf") else 1.0


def exposes_in_wall_time(spec: DeviceSpec) -> bool:
    """False for a simulated camera that renders at once (its URL without ``realtime=1``)."""
    if spec.driver != "sim_camera":
        return True
    return _query(spec.url).get("realtime", "0").strip().lower() in ("1", "true", "yes")


@dataclass(frozen=True)
class BenchTiming:
    """What the profile says about time on this bench (see the module docstring).

    ``axis_speed`` maps an axis role to its clock speed-up, ``home_s`` to the wall-clock
    seconds its homing takes; ``exposure_factor`` is 1 when exposures take wall time,
    else 0.
    """

    axis_speed: dict[str, float]
    home_s: dict[str, float] = field(default_factory=dict)
    exposure_factor: float = 1.0
    frame_overhead_s: float = 0.0
    scene_change_s: float = 0.0
    point_overhead_s: float = POINT_OVERHEAD_S
    #: One settling wait of the lock-in's output filter (s; 0 without a lock-in).
    lockin_settle_s: float = 0.0
    #: The lock-in's time constant τ (s; 0 without a lock-in).
    lockin_tau_s: float = 0.0
    #: The filter wheel's slots (0: no wheel).
    wheel_slots: int = 0
    #: How many times faster than the FW102C's high speed the wheel turns (an emulated
    #: wheel's clock ``speed=``; 0.5 at the normal speed, ``wheel_speed=0``).
    wheel_speed: float = 1.0
    #: What the estimate assumed because the profile did not say (in words).
    assumed: tuple[str, ...] = ()
    #: Seconds the simulated scene takes to render a lit view beyond ``scene_change_s``
    #: (the light-field wall's cost model, :mod:`instrument.bench.render_cost`; 0 where
    #: the camera's ``scene_change_s`` already holds the render).
    render_s: float = 0.0
    #: CPU seconds of one aperture integral of the emulated power meter and of the
    #: emulated lock-in's photodiode, (light on, light off); zeros for real detectors.
    power_meter_integral_s: tuple[float, float] = (0.0, 0.0)
    lockin_integral_s: tuple[float, float] = (0.0, 0.0)

    @property
    def emulated(self) -> bool:
        """True when some axis runs faster than real time."""
        return any(s != 1.0 for s in self.axis_speed.values())

    def lockin_reading_s(self, frames: int) -> float:
        """Seconds one lock-in reading takes: a settling wait per snapshot (at least four,
        as the engine reads) and two to choose the range."""
        return self.lockin_settle_s * (max(int(frames), 4) + 2)

    def pem_reading_s(self, time_constants: float, reads: int) -> float:
        """Seconds one PEM setting's readings take (:mod:`instrument.run.pem_reading`): per
        harmonic (1f, 2f) a settle of ``time_constants`` τ, then the engine's lock-in
        reading of ``reads`` snapshots (:meth:`lockin_reading_s`)."""
        per = time_constants * self.lockin_tau_s + self.lockin_reading_s(reads)
        return 2.0 * per

    def wheel_move_s(self, start: int, end: int) -> float:
        """Seconds the filter wheel takes from slot ``start`` to ``end`` (the shorter way
        round); 0 for the same slot or without a wheel."""
        if start == end or self.wheel_slots <= 0:
            return 0.0
        steps = abs(end - start) % self.wheel_slots
        steps = min(steps, self.wheel_slots - steps)
        return (steps * 360.0 / self.wheel_slots * WHEEL_S_PER_DEG
                + WHEEL_SETTLE_S) / self.wheel_speed


def bench_timing(profile: BenchProfile, axes: Iterable[str] = ()) -> BenchTiming:
    """The timing of ``profile`` for a plan moving ``axes``."""
    speed, home = {}, {}
    for role in axes:
        spec = profile.devices.get(role)
        speed[role] = 1.0 if spec is None else clock_speed(spec)
        home[role] = 0.0 if spec is None else spec.home_s / speed[role]
    assumed: list[str] = []
    camera = next((d for d in profile.devices.values()
                   if d.kind == "camera"), None)
    costs = {"frame_overhead_s": 0.0, "scene_change_s": 0.0}
    if camera is not None:
        defaults = CAMERA_DEFAULTS.get(camera.driver)  # None: a plugin's camera
        for key in costs:
            costs[key] = getattr(camera, key)
            if key not in camera.timing_declared:
                costs[key] = 0.0 if defaults is None else defaults[key]
                why = (f"no default for driver {camera.driver!r}; give it in the profile"
                       if defaults is None else f"the {camera.driver} default")
                assumed.append(f"{camera.role}.{key} not in the profile: {costs[key]:.3g} s "
                               f"assumed ({why})")
    lockin = next((d for d in profile.devices.values() if d.driver == "sr830"), None)
    settle = tau = 0.0
    if lockin is not None:
        tau = float(lockin.settings.get("time_constant_s", LOCKIN_POWER_UP[0]))
        slope = int(lockin.settings.get("filter_slope_db_per_oct", LOCKIN_POWER_UP[1]))
        settle = LockIn.SETTLE_TIME_CONSTANTS.get(slope, 10.0) * tau
        if "time_constant_s" not in lockin.settings:
            assumed.append(f"{lockin.role}: no time constant in its settings; the SR830's "
                           f"power-up {tau:g} s at {slope} dB/oct assumed")
    wheel = next((d for d in profile.devices.values() if d.driver == "fw102c"), None)
    slots, wheel_speed = 0, 1.0
    if wheel is not None:
        slots = 12 if "slots=12" in wheel.url or wheel.options.get("slots") == 12 else 6
        normal = _query(wheel.url).get("wheel_speed", "1").strip() == "0"
        wheel_speed = clock_speed(wheel) * (0.5 if normal else 1.0)
    return BenchTiming(speed, home,
                       1.0 if camera is None or exposes_in_wall_time(camera) else 0.0,
                       costs["frame_overhead_s"], costs["scene_change_s"],
                       lockin_settle_s=settle, lockin_tau_s=tau, wheel_slots=slots,
                       wheel_speed=wheel_speed,
                       assumed=tuple(assumed),
                       render_s=_scene_render_s(profile, camera),
                       power_meter_integral_s=_integral_s(profile, "pm100usb"),
                       lockin_integral_s=_integral_s(profile, "sr830"))


def _integral_s(profile: BenchProfile, driver: str) -> tuple[float, float]:
    """(light on, light off) seconds of one aperture integral of the bench's emulated
    ``driver`` detector bound to a simulated goniometer world; zeros for a real one."""
    spec = next((d for d in profile.devices.values() if d.driver == driver), None)
    scene = (profile.simulation or {}).get("scene")
    scene = scene if isinstance(scene, dict) else {}
    if spec is None or not urlsplit(spec.url).scheme.startswith("sim") \
            or "world" not in _query(spec.url) or scene.get("kind") is not None:
        return 0.0, 0.0  # a real detector, or a light-field or spheres scene (not measured)
    lit, dark = SIM_APERTURE_INTEGRAL_S.get(str(scene.get("brdf")),
                                            SIM_APERTURE_INTEGRAL_S["default"])
    try:
        m = int(scene.get("aperture_samples", SIM_APERTURE_SAMPLES))
    except (TypeError, ValueError):
        m = SIM_APERTURE_SAMPLES  # the world refuses it when the bench opens
    # The lit integral evaluates the BRDF at every footprint point for every aperture node;
    # the dark one only the ambient term, whatever the rule.
    return lit * aperture_nodes(m) / aperture_nodes(SIM_APERTURE_SAMPLES), dark


def aperture_nodes(aperture_samples: int) -> int:
    """Nodes of the emulator's rule over a detector aperture for a scene's
    ``aperture_samples`` m: ⌈m/3⌉ rings of 4⌈m/3⌉ angles
    (``hw_mocks.sim.goniometer_scene.aperture_rule``; 36 at the default 9, 324 at 27)."""
    rings = max(1, math.ceil(aperture_samples / 3))
    return 4 * rings * rings


def _scene_render_s(profile: BenchProfile, camera: DeviceSpec | None) -> float:
    """The render cost of one lit view of a simulated light-field scene (0 otherwise)."""
    scene = (profile.simulation or {}).get("scene")
    if camera is None or camera.driver != "sim_camera" or not isinstance(scene, dict) \
            or scene.get("kind") != "lightfield":
        return 0.0
    try:
        columns = int(_query(camera.url).get("width", SIM_CAMERA_WIDTH))
    except ValueError:
        columns = SIM_CAMERA_WIDTH
    return lightfield_render_s(scene, columns)
