"""The virtual bench: one physical world shared by every simulated device.

A :class:`VirtualBench` holds

* the **axis positions**, read live from the firmware emulators in :mod:`hw_mocks.registry`
  (``emulator.stage.physical_position()``, degrees or millimetres) and keyed by role
  (``sample_theta``, ``sample_phi``, ``sample_tilt``, ``detector_theta``, ``source_theta``,
  ``camera_z``), so a move commanded through a real driver moves the world;
* the **source** state (on/off, power, wavelength, beam radius), changed by
  :class:`hw_mocks.sim.source.SimulatedSource`;
* the **light path** between source and sample: an optional shutter (the SC10 emulator)
  and an optional filter wheel (the FW102C emulator) with the filters in its slots, both
  read live from the emulators. :meth:`VirtualBench.light_at_sample` is the light as it
  reaches the sample (source on *and* shutter open, spectrum through the selected
  filter); every snapshot's ``source`` is that light, so the camera and the power meter
  follow the shutter and the filter;
* a **scene** (this module knows only its protocol; :mod:`hw_mocks.sim.goniometer_scene`
  implements the goniometer scene).

It provides the optical power at the power-meter head (:meth:`VirtualBench.optical_power_w`,
the callable the PM100USB emulator is given) and the camera pose for the simulated camera.

Lab frame and kinematics (stated once here)
-------------------------------------------
Right-handed lab frame: **y** is the common rotation axis of ``sample_theta``,
``detector_theta`` and ``source_theta``; **z** points from the sample towards the source
when every axis reads 0; x completes the frame (the plane of incidence is x–z). Lengths in
mm, angles in degrees at the interface (radians inside). ``R_a(θ)`` is a right-handed
rotation by θ about axis a.

* Direction towards the source: ``ω_s = R_y(source_theta) ẑ``.
* Sample frame: ``R = R_y(sample_theta) · R_z(180°) · R_x(sample_tilt) · R_z(sample_phi)``
  maps the sample's own axes (x_s, y_s, n) = R (x̂, ŷ, ẑ); the normal n is ẑ at zero, x_s
  lies in the plane of incidence on the source side (so the source is at φi = 0 for
  sample_theta > 0) and y_s points down (−ŷ). ``sample_theta`` turns the mount about the
  lab axis, a positive ``sample_tilt`` raises the normal towards +ŷ (out of the plane of
  incidence) and ``sample_phi`` spins the sample about its normal (right-handed).
  This is the convention of :mod:`instrument.bench.kinematics` (its +Z "up" is this ŷ, its
  horizontal plane this x–z plane) when the profile's ``source_theta_deg`` is 0; a
  ``source_theta`` role here is a physical source arm, which does not move the other axes'
  zeros.
* Detector arm direction: ``ω_d = R_y(detector_theta) ẑ``; the camera (or the power-meter
  head) sits at ``(arm_length_mm + camera_z) · ω_d`` looking at the origin, image "up" = ŷ.
* Type (i) goniometer (any of the roles ``source_arc``, ``source_azimuth``,
  ``detector_arc``, ``detector_azimuth``): the sample lies still with its normal up,
  (x_s, y_s, n) = (ẑ, x̂, ŷ), and the source and detector directions are the arms'
  ``(sin a cos ϕ, sin a sin ϕ, cos a)`` in that frame (a the arc, ϕ the azimuth: the
  convention of :class:`instrument.bench.kinematics.TypeIKinematics`, whose lab X, Y, Z
  are this ẑ, x̂, ŷ). The other rotation roles are ignored there.
* The scattering angles follow :mod:`analysis.brdf.geometry`: θ from the normal,
  φ = atan2(ω·y_s, ω·x_s). With ``sample_theta = θ > 0`` and ``detector_theta = 2θ`` the
  detector sits in the specular direction (θi = θr = θ, φi = 0, φr = π): the classic θ–2θ
  geometry. The detector cannot reach ``detector_theta = 0`` without blocking the beam.
"""

from __future__ import annotations

import importlib
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hw_mocks import registry
from hw_mocks.sim.filters import parse_bands, transmit
from hw_mocks.sim.polarisation import HiddenTrain
from hw_mocks.sim.state import (
    ARM_ROLES,
    ROLES,
    BenchPose,
    LightPath,
    PowerMeterHead,
    Scene,
    SourceState,
    WorldState,
    rotation,
)

__all__ = [
    "SPIN_ROLE",
    "BenchPose",
    "LightPath",
    "PowerMeterHead",
    "RoleSpec",
    "Scene",
    "SourceState",
    "VirtualBench",
    "WorldState",
    "configure_world",
    "get_world",
    "reset_worlds",
    "rotation",
]


@dataclass(frozen=True)
class RoleSpec:
    """Where one role's position comes from.

    Either ``url`` (an emulator, ``scheme://name?options``; its stage's physical position)
    or the constant ``value``. ``scale`` and ``offset`` map the stage to the world
    (``world = scale · stage + offset``): a sign flip, or a mounting offset to be found by a
    calibration. ``address`` picks one module of an emulator that carries several on one
    bus (an Elliptec bus, ``simell://bus?addresses=0123``: the emulator's
    ``stage_at(address)``); without it the emulator's one ``stage`` is read.
    """

    url: str | None = None
    value: float = 0.0
    scale: float = 1.0
    offset: float = 0.0
    address: str | None = None

    @classmethod
    def parse(cls, spec: Any) -> RoleSpec:
        if isinstance(spec, RoleSpec):
            return spec
        if isinstance(spec, int | float):
            return cls(value=float(spec))
        if isinstance(spec, str):
            registry.parse_url(spec)  # validates the form
            return cls(url=spec)
        if isinstance(spec, Mapping):
            unknown = set(spec) - {"url", "value", "scale", "offset", "address"}
            if unknown:
                raise ValueError(f"unknown role keys {sorted(unknown)}")
            if spec.get("url") is not None:
                registry.parse_url(str(spec["url"]))
            address = spec.get("address")
            if address is not None and spec.get("url") is None:
                raise ValueError(f"a role's 'address' ({address!r}) needs the bus's 'url'")
            return cls(
                url=spec.get("url"), value=float(spec.get("value", 0.0)),
                scale=float(spec.get("scale", 1.0)), offset=float(spec.get("offset", 0.0)),
                address=None if address is None else str(address).upper(),
            )
        raise TypeError(f"a role is a URL, a number or a table, got {spec!r}")


def _emulator_for(url: str):
    """The emulator behind ``url``, created through its URL handler's factory if needed
    (so the world and a driver that connects later share one instance)."""
    scheme, name, options = registry.parse_url(url)
    try:
        return registry.get(scheme, name)
    except KeyError:
        pass
    try:
        module = importlib.import_module(f"hw_mocks.urlhandler.protocol_{scheme}")
    except ImportError as err:
        raise KeyError(f"no emulator {scheme}://{name} and no URL handler for {scheme}://") \
            from err
    factory = module.Serial.factory
    return registry.get_or_create(scheme, name, factory, options)


class VirtualBench:
    """The physical world of the simulated bench.

    Parameters
    ----------
    name
        Registry name (``get_world(name)``).
    roles
        Role → :class:`RoleSpec` (or its plain form: URL string, number, or table).
        Roles not given read 0 (``camera_z`` 0 mm, angles 0°).
    scene
        The scene; default: the goniometer scene with a Lambertian sample.
    source
        Initial source state.
    arm_length_mm
        Distance from the sample centre to the camera pinhole at ``camera_z = 0``.
    power_meter
        Geometry of the power-meter head on the detector arm.
    light_path
        Shutter and filter wheel between the source and the sample (default: none).
    """

    def __init__(
        self,
        name: str = "sim",
        *,
        roles: Mapping[str, Any] | None = None,
        scene: Scene | None = None,
        source: SourceState | None = None,
        arm_length_mm: float = 300.0,
        power_meter: PowerMeterHead | None = None,
        light_path: LightPath | None = None,
        optics: HiddenTrain | None = None,
    ) -> None:
        self.name = name
        self._lock = threading.RLock()
        self._roles: dict[str, RoleSpec] = {}
        for role, spec in (roles or {}).items():
            self._roles[role] = RoleSpec.parse(spec)
        if scene is None:
            from hw_mocks.sim.goniometer_scene import GoniometerScene

            scene = GoniometerScene()
        self._scene = scene
        self._source = source or SourceState()
        if not arm_length_mm > 0:
            raise ValueError("arm_length_mm must be > 0")
        self.arm_length_mm = float(arm_length_mm)
        self.power_meter = power_meter or PowerMeterHead()
        self._light_path = light_path or LightPath()
        self._optics = optics
        self._version = 0
        self._power_cache: dict[tuple, float] = {}
        self._bound_meter: Any = None  # the PM100USB firmware reading this world

    # configuration --------------------------------------------------------------
    @classmethod
    def from_config(cls, name: str, config: Mapping[str, Any]) -> VirtualBench:
        """Build from a plain dict (the bench profile's ``[simulation]`` table).

        Keys: ``roles`` (role → URL | number | {url, scale, offset, value}), ``scene``
        (see :meth:`hw_mocks.sim.goniometer_scene.GoniometerScene.from_config`; with
        ``kind = "lightfield"``
        :meth:`hw_mocks.sim.lightfield_bench.LightFieldBenchScene.from_config`; with
        ``kind = "spheres"`` :meth:`hw_mocks.sim.sphere_bench.SphereBenchScene.from_config`;
        with ``kind = "integrating_sphere"`` a uniform target,
        :meth:`hw_mocks.sim.uniform_target.IntegratingSphereTarget.from_config`),
        ``source`` ({power_w, wavelength_nm, beam_radius_mm, max_power_w, on}),
        ``arm_length_mm``, ``power_meter`` ({distance_mm, aperture_diameter_mm, url}),
        ``shutter`` (a ``simsc10://`` URL) and ``filter_wheel`` ({url, filters}; see
        :class:`~hw_mocks.sim.state.LightPath`); ``optics``, a polarimeter's hidden
        elements (:class:`~hw_mocks.sim.polarisation.HiddenTrain`), which with
        ``scene.kind = "polarimetric"``
        (:class:`~hw_mocks.sim.polarimetric_scene.PolarimetricScene`) make the world carry
        Stokes vectors. With a power-meter ``url`` the PM100USB emulator is created and
        bound (:meth:`bind_power_meter`).
        """
        known = {"roles", "scene", "source", "arm_length_mm", "power_meter", "shutter",
                 "filter_wheel", "optics"}
        unknown = set(config) - known
        if unknown:
            raise ValueError(f"unknown [simulation] keys {sorted(unknown)}; known {sorted(known)}")
        scene_cfg = dict(config.get("scene", {}))
        if scene_cfg.get("kind") == "lightfield":
            from hw_mocks.sim.lightfield_bench import LightFieldBenchScene

            scene: Scene = LightFieldBenchScene.from_config(scene_cfg)
        elif scene_cfg.get("kind") == "spheres":
            from hw_mocks.sim.sphere_bench import SphereBenchScene

            scene = SphereBenchScene.from_config(scene_cfg)
        elif scene_cfg.get("kind") == "integrating_sphere":
            from hw_mocks.sim.uniform_target import IntegratingSphereTarget

            scene = IntegratingSphereTarget.from_config(scene_cfg)
        elif scene_cfg.get("kind") == "polarimetric":
            from hw_mocks.sim.polarimetric_scene import PolarimetricScene

            scene = PolarimetricScene.from_config(scene_cfg)
        else:
            from hw_mocks.sim.goniometer_scene import GoniometerScene

            scene = GoniometerScene.from_config(scene_cfg)
        source = SourceState(**dict(config.get("source", {})))
        pm = PowerMeterHead(**dict(config.get("power_meter", {})))
        light_path = LightPath.from_config(config.get("shutter"), config.get("filter_wheel"))
        optics = None
        if config.get("optics") is not None:
            optics = HiddenTrain.from_config(config["optics"])
        world = cls(
            name, roles=config.get("roles"), scene=scene, source=source,
            arm_length_mm=float(config.get("arm_length_mm", 300.0)), power_meter=pm,
            light_path=light_path, optics=optics,
        )
        if pm.url is not None:
            world.bind_power_meter()
        return world

    def adopt(self, other: VirtualBench) -> None:
        """Take over another world's roles, scene, source and geometry (reconfiguration);
        a power meter bound to ``other`` is re-bound to this world."""
        with self._lock:
            self._roles = dict(other._roles)
            self._scene = other._scene
            self._source = other._source
            self.arm_length_mm = other.arm_length_mm
            self.power_meter = other.power_meter
            self._light_path = other._light_path
            self._optics = other._optics
            self._version += 1
            self._power_cache.clear()
        if self.power_meter.url is not None:
            self.bind_power_meter()

    def set_role(self, role: str, spec: Any) -> None:
        with self._lock:
            self._roles[role] = RoleSpec.parse(spec)
            self._version += 1

    @property
    def roles(self) -> dict[str, RoleSpec]:
        return dict(self._roles)

    # state ------------------------------------------------------------------------
    @property
    def scene(self) -> Scene:
        return self._scene

    @scene.setter
    def scene(self, scene: Scene) -> None:
        with self._lock:
            self._scene = scene
            self._version += 1

    @property
    def source(self) -> SourceState:
        return self._source

    def update_source(self, **changes: Any) -> SourceState:
        """Change source fields (``on``, ``power_w``, ...); returns the new state.

        A bound power meter follows the light's wavelength at every reading
        (:meth:`light_wavelength_nm`).
        """
        with self._lock:
            new = replace(self._source, **changes)
            if not 0.0 <= new.power_w <= new.max_power_w:
                raise ValueError(f"power {new.power_w:g} W outside [0, {new.max_power_w:g}] W")
            self._source = new
            return new

    def position(self, role: str) -> float:
        """World position of ``role`` (deg or mm)."""
        spec = self._roles.get(role)
        if spec is None:
            return 0.0
        if spec.url is None:
            return spec.value
        emulator = _emulator_for(spec.url)
        # The stage updates itself when read; the link's thread may be moving it now.
        with emulator.lock:
            stage = emulator.stage if spec.address is None else emulator.stage_at(spec.address)
            physical = float(stage.physical_position())
        return spec.scale * physical + spec.offset

    def spin(self) -> tuple[float, float]:
        """(angle in degrees, rate in degrees/s) of the sample spinner: the stage bound to
        the role :data:`SPIN_ROLE`, which turns the sample about its own normal; (0, 0)
        without one. Not part of the pose: it matters to coherent light alone (speckle,
        :mod:`hw_mocks.sim.speckle`), the samples being isotropic about their normal."""
        spec = self._roles.get(SPIN_ROLE)
        if spec is None:
            return 0.0, 0.0
        if spec.url is None:
            return spec.value, 0.0
        emulator = _emulator_for(spec.url)
        with emulator.lock:
            angle = float(emulator.stage.physical_position())
            rate = float(emulator.stage.velocity_now())
        return spec.scale * angle + spec.offset, spec.scale * rate

    def positions(self) -> dict[str, float]:
        return {role: self.position(role) for role in ROLES}

    def pose(self, positions: Mapping[str, float] | None = None) -> BenchPose:
        p = dict(positions) if positions is not None else self.positions()
        if any(r in self._roles for r in ARM_ROLES):
            return self._arms_pose(p)
        rad = {k: math.radians(p.get(k, 0.0)) for k in ROLES if k != "camera_z"}
        z = np.array([0.0, 0.0, 1.0])
        source_dir = rotation("y", rad["source_theta"]) @ z
        r = (rotation("y", rad["sample_theta"]) @ rotation("z", math.pi)
             @ rotation("x", rad["sample_tilt"]) @ rotation("z", rad["sample_phi"]))
        detector_dir = rotation("y", rad["detector_theta"]) @ z
        return BenchPose(
            source_dir=source_dir, sample_axes=r.T.copy(), detector_dir=detector_dir,
            detector_distance_mm=self.arm_length_mm + p.get("camera_z", 0.0),
        )

    def _arms_pose(self, p: Mapping[str, float]) -> BenchPose:
        """The pose of a type (i) goniometer (module docstring)."""
        def arm(name: str) -> np.ndarray:
            a = math.radians(p.get(f"{name}_arc", 0.0))
            az = math.radians(p.get(f"{name}_azimuth", 0.0))
            sx, sy, sz = math.sin(a) * math.cos(az), math.sin(a) * math.sin(az), math.cos(a)
            return np.array([sy, sz, sx])  # sample (x_s, y_s, n) = world (ẑ, x̂, ŷ)

        axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        return BenchPose(source_dir=arm("source"), sample_axes=axes,
                         detector_dir=arm("detector"),
                         detector_distance_mm=self.arm_length_mm + p.get("camera_z", 0.0))

    def snapshot(self) -> WorldState:
        """Everything a device needs to render the world now, with a cache key."""
        with self._lock:
            positions = self.positions()
            source, scene, version = self.light_at_sample(), self._scene, self._version
            optics = self._optics
        key: tuple = (
            self.name, version, id(scene),
            tuple(round(positions[k], 9) for k in ROLES),
            source,
        )
        if optics is None:
            return WorldState(positions=positions, pose=self.pose(positions), source=source,
                              scene=scene, key=key)
        # a polarimetric bench: the elements' mounts are part of the state (and its key)
        mounts = {role: self.position(role) for role in optics.mounts}
        key += (tuple(round(mounts[r], 9) for r in optics.mounts),)
        pems = {url: _modulator_reading(url) for url in optics.modulators}
        key += (tuple(round(pems[u][0], 9) for u in optics.modulators),)
        state = optics.state(mounts.__getitem__, source.wavelength_nm, pems.__getitem__)
        return WorldState(positions=positions, pose=self.pose(positions), source=source,
                          scene=scene, key=key, optics=state)

    @property
    def optics(self) -> HiddenTrain | None:
        """The hidden polarisation optics (``[simulation.optics]``), None without."""
        return self._optics

    # light path ---------------------------------------------------------------------
    @property
    def light_path(self) -> LightPath:
        return self._light_path

    def bind_shutter(self, target: Any) -> None:
        """Put a shutter in the beam: an SC10 emulator or its ``simsc10://`` URL
        (``None`` takes it out)."""
        url = None if target is None else _url_of(target)
        with self._lock:
            self._light_path = replace(self._light_path, shutter=url)
            self._version += 1

    def bind_filter_wheel(self, target: Any, filters: Mapping[Any, Any] | None = None) -> None:
        """Put a filter wheel in the beam: an FW102C emulator or its ``simfw102c://`` URL
        (``None`` takes it out). ``filters`` (slot → band table) replaces the slots' filters;
        ``None`` keeps those configured."""
        url = None if target is None else _url_of(target)
        with self._lock:
            changes: dict[str, Any] = {"filter_wheel": url}
            if filters is not None:
                changes["filters"] = parse_bands(filters)
            self._light_path = replace(self._light_path, **changes)
            self._version += 1

    def light_wavelength_nm(self) -> float:
        """Centre wavelength (nm) of the light reaching the detectors now: the filter's in
        the beam, else the source's (with the light off, the source's: a dark reading has
        no colour)."""
        light = self.light_at_sample()
        return float(light.wavelength_nm if light.on else self._source.wavelength_nm)

    def light_at_sample(self) -> SourceState:
        """The light as it reaches the sample now.

        Off unless the source is on, the shutter (if any) is open and the filter wheel (if
        any) stands at a slot; its power, centre wavelength and bandwidth are those passed
        by the filter in that slot (:func:`hw_mocks.sim.filters.transmit`).
        """
        with self._lock:
            source, path = self._source, self._light_path
        if path.shutter is not None:
            shutter = _emulator_for(path.shutter)
            if not shutter.light_passes():
                return replace(source, on=False)
        if path.filter_wheel is not None:
            slot = _emulator_for(path.filter_wheel).slot_at_beam()
            if slot is None:  # turning or stuck: the beam falls between the apertures
                return replace(source, on=False)
            source = transmit(source, path.filters.get(slot))
        return source

    # devices ------------------------------------------------------------------------
    def optical_power_w(self, wavelength_nm: float | None = None) -> float:
        """Optical power (W) arriving on the power-meter head.

        The head sits on the detector arm at ``power_meter.distance_mm`` facing the sample;
        the scene integrates scattered light over the footprint and the aperture, adds the
        direct beam where nothing blocks it, ambient light and the instrument signature.
        The source is monochromatic (``source.wavelength_nm``): ``wavelength_nm`` is the
        wavelength the asker believes the light has, accepted for the PM100USB emulator's
        ``optical_power_w(wavelength_nm)`` interface; the physical power does not depend on
        it (the emulator applies its own responsivity mismatch).
        """
        state = self.snapshot()
        key = (state.key, self.power_meter)
        cached = self._power_cache.get(key)
        if cached is not None:
            return cached
        pose = state.pose
        center = pose.detector_dir * self.power_meter.distance_mm
        power = state.scene.power_on_aperture(
            center, -pose.detector_dir, self.power_meter.aperture_diameter_mm, state
        )
        if len(self._power_cache) > 256:
            self._power_cache.clear()
        self._power_cache[key] = power
        return power

    def reading_state(self) -> tuple[tuple[float, ...], SourceState]:
        """What a detector's reading depends on now: every role's position (rounded far
        below any stage's resolution) and the light at the sample. A bound power meter
        keys its noise to it (:mod:`hw_mocks.firmware.pm100usb`)."""
        positions = self.positions()
        return tuple(round(positions[k], 9) for k in ROLES), self.light_at_sample()

    def power_callable(self) -> Callable[[float], float]:
        """The ``optical_power_w(wavelength_nm) -> W`` callable for the PM100USB emulator."""
        return self.optical_power_w

    def bind_power_meter(self, target: Any = None) -> Any:
        """Connect a PM100USB firmware model to this world and return it.

        ``target`` is the firmware object, a ``simusb://name`` URL (the device is created
        through :func:`hw_mocks.usb.backend_from_url` if needed), or ``None`` for
        ``power_meter.url``. Sets its ``optical_power_w`` callable, the light's
        wavelength (followed at every reading: :meth:`light_wavelength_nm`) and the state
        its noise is keyed to (:meth:`reading_state`), so that readings the bench takes
        while it rests (a server's idle polls) leave a run's readings unchanged (ADR 0111).
        """
        target = self.power_meter.url if target is None else target
        if target is None:
            raise ValueError("no power meter to bind: give a firmware or a simusb:// URL")
        if isinstance(target, str):
            from hw_mocks import usb

            _scheme, name, _options = registry.parse_url(target)
            usb.backend_from_url(target)
            target = usb.get_firmware(name)
        target.optical_power_w = self.optical_power_w
        target.light_wavelength_nm = self.light_wavelength_nm
        target.noise_state = self.reading_state
        target.bound_world = self.name
        self._bound_meter = target
        return target


def _modulator_reading(url: str) -> tuple[float, float]:
    """(drive 0..1, frequency Hz) of a PEM controller's emulator now."""
    emulator = _emulator_for(url)
    with emulator.lock:
        drive = 0.0 if emulator.faulted else float(emulator.drive)
    return drive, float(emulator.resonance_hz())


def _url_of(target: Any) -> str:
    """``scheme://name`` of an emulator, or a URL string as given (validated)."""
    if isinstance(target, str):
        registry.parse_url(target)
        return target
    scheme, name = getattr(target, "scheme", ""), getattr(target, "name", "")
    if not scheme or not name:
        raise TypeError(f"expected an emulator or a URL, got {target!r}")
    return f"{scheme}://{name}"


#: The role of a sample spinner (:meth:`VirtualBench.spin`).
SPIN_ROLE = "sample_spin"

_worlds: dict[str, VirtualBench] = {}


_worlds_lock = threading.Lock()


def find_world(name: str) -> VirtualBench | None:
    """The world called ``name``, or ``None`` if it has not been made."""
    with _worlds_lock:
        return _worlds.get(name)


def get_world(name: str = "sim") -> VirtualBench:
    """The world called ``name``, created with default settings if new."""
    with _worlds_lock:
        world = _worlds.get(name)
        if world is None:
            world = _worlds[name] = VirtualBench(name)
        return world


def configure_world(name: str, config: Mapping[str, Any] | VirtualBench) -> VirtualBench:
    """Configure the world ``name`` from a ``[simulation]`` dict (or install a world).

    A world that exists already is reconfigured in place, so devices that hold it (a
    camera opened earlier) see the new configuration; a new one is created otherwise.
    """
    new = config if isinstance(config, VirtualBench) else VirtualBench.from_config(name, config)
    with _worlds_lock:
        old = _worlds.get(name)
        if old is None or isinstance(config, VirtualBench):
            _worlds[name] = new
            return new
    old.adopt(new)
    return old


def reset_worlds() -> None:
    """Forget every world (tests call this with :func:`hw_mocks.registry.reset`)."""
    with _worlds_lock:
        _worlds.clear()


registry.register_world_lookup(find_world)
