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
view). Homing an axis takes ``home_s`` of its own time (the profile says how long; an
emulated axis takes that divided by its speed-up). :func:`bench_timing` collects these from
a profile so that an estimate says what *this* bench will take.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

from instrument.bench.profile import BenchProfile, DeviceSpec

__all__ = ["POINT_OVERHEAD_S", "BenchTiming", "bench_timing", "clock_speed",
           "exposes_in_wall_time"]

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

    @property
    def emulated(self) -> bool:
        """True when some axis runs faster than real time."""
        return any(s != 1.0 for s in self.axis_speed.values())


def bench_timing(profile: BenchProfile, axes: Iterable[str] = ()) -> BenchTiming:
    """The timing of ``profile`` for a plan moving ``axes``."""
    speed, home = {}, {}
    for role in axes:
        spec = profile.devices.get(role)
        speed[role] = 1.0 if spec is None else clock_speed(spec)
        home[role] = 0.0 if spec is None else spec.home_s / speed[role]
    camera = next((d for d in profile.devices.values()
                   if d.driver in ("sim_camera", "opencv_camera")), None)
    if camera is None:
        return BenchTiming(speed, home)
    return BenchTiming(speed, home, 1.0 if exposes_in_wall_time(camera) else 0.0,
                       camera.frame_overhead_s, camera.scene_change_s)
