"""A chopped photodiode on the detector arm, feeding the emulated SR830 lock-in.

The virtual bench (:mod:`hw_mocks.sim.world`) gives the optical power on an aperture on
the detector arm. A chopper in the source beam switches the *source-borne* light on and
off (a 50 % square wave at the chopper frequency, whose reference output drives the
lock-in's REF IN); ambient light reaches the detector unchopped. The photodiode turns
power into current with its responsivity R (A/W), a transimpedance amplifier into
voltage with its gain G (V/A).

What the lock-in sees (a 0…P square wave of 50 % duty is P/2 + (2P/π) sin ωt + harmonics
at 3ω, 5ω…)::

    fundamental, volts rms  = (√2/π) · R · G · P_source      ≈ 0.450 · R · G · P_source
    DC, volts               = R · G · (P_source/2 + P_ambient)

The lock-in reports the rms of the fundamental (SR830 manual, Rev. 2.5, p. 3-3: a 2 V
pk-pk square wave has a fundamental of 1.273 V peak, displayed as its rms 0.90 V), so a
chopped peak-to-peak signal V reads R = (√2/π)·V. The DC part (ambient light, and half the
chopped light) is rejected. The signal is taken in phase with the chopper's reference
(phase 0; a real set-up has a delay that ``PHAS``/auto-phase removes).

Noise at the input: the emulator's amplifier noise density combined in quadrature with
the shot noise of the whole photocurrent, G·√(2 q I) with I = R·(P_source/2 + P_ambient):
ambient light does not add signal, but it adds noise.

Geometry: the photodiode's aperture sits where the power-meter head does
(``VirtualBench.power_meter``: on the detector arm at ``distance_mm`` facing the sample),
with the head's aperture diameter unless ``aperture_diameter_mm`` is given.

:func:`bind_lockin` connects an :class:`~hw_mocks.firmware.sr830.Sr830Emulator` to a world
by name, the way a ``simusb://…?world=sim`` power meter reads its light; the world is
looked up at every reading, so the lock-in may be created before the world is configured
(it reads darkness until then).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace
from typing import Any

from hw_mocks.firmware.sr830 import InputSignal, Sr830Emulator
from hw_mocks.sim.world import VirtualBench, find_world

__all__ = ["ELEMENTARY_CHARGE_C", "ChoppedPhotodiode", "LockInBinding",
           "ModulatedLockInBinding", "bind_lockin", "split_power_w"]

ELEMENTARY_CHARGE_C = 1.602176634e-19
#: Fundamental (rms) of a 0…1 square wave of 50 % duty: (2/π)/√2 = √2/π.
SQUARE_FUNDAMENTAL_RMS = math.sqrt(2.0) / math.pi


@dataclass(frozen=True)
class ChoppedPhotodiode:
    """A photodiode with a transimpedance amplifier behind a 50 % duty chopper.

    ``responsivity_a_per_w`` (A/W) and ``transimpedance_v_per_a`` (V/A) must be > 0;
    ``aperture_diameter_mm`` ``None`` uses the world's power-meter head aperture.
    """

    responsivity_a_per_w: float = 0.4
    transimpedance_v_per_a: float = 1e6
    aperture_diameter_mm: float | None = None

    def __post_init__(self) -> None:
        for label, value in (("responsivity_a_per_w", self.responsivity_a_per_w),
                             ("transimpedance_v_per_a", self.transimpedance_v_per_a)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{label} must be a finite number > 0, got {value}")
        if self.aperture_diameter_mm is not None and not self.aperture_diameter_mm > 0:
            raise ValueError("aperture_diameter_mm must be > 0")

    @property
    def volts_per_watt(self) -> float:
        return self.responsivity_a_per_w * self.transimpedance_v_per_a

    def signal(self, source_w: float, ambient_w: float, *, chopper_hz: float | None,
               amplifier_noise_v_per_rthz: float = 0.0) -> InputSignal:
        """The lock-in input for ``source_w`` of chopped and ``ambient_w`` of steady light."""
        if source_w < 0 or ambient_w < 0:
            raise ValueError("optical powers must be >= 0")
        mean_current_a = self.responsivity_a_per_w * (source_w / 2.0 + ambient_w)
        shot = self.transimpedance_v_per_a * math.sqrt(2.0 * ELEMENTARY_CHARGE_C
                                                       * mean_current_a)
        return InputSignal(
            ac_rms_v=SQUARE_FUNDAMENTAL_RMS * self.volts_per_watt * source_w,
            phase_deg=0.0,
            # No chopper: the light is not modulated and nothing reaches X and Y.
            frequency_hz=chopper_hz if chopper_hz else 0.0,
            dc_v=self.volts_per_watt * (source_w / 2.0 + ambient_w),
            noise_v_per_rthz=math.hypot(amplifier_noise_v_per_rthz, shot),
        )


def split_power_w(world: VirtualBench, aperture_diameter_mm: float | None = None
                  ) -> tuple[float, float]:
    """(source-borne, ambient) optical power in W on the detector-arm aperture.

    The source-borne part is what the chopper modulates: the power with the source as it
    is minus the power with the source off (ambient light only).
    """
    state = world.snapshot()
    pose = state.pose
    head = world.power_meter
    diameter = head.aperture_diameter_mm if aperture_diameter_mm is None \
        else aperture_diameter_mm
    center = pose.detector_dir * head.distance_mm
    facing = -pose.detector_dir
    total = state.scene.power_on_aperture(center, facing, diameter, state)
    if not state.source.on:
        return 0.0, total
    dark = replace(state, source=replace(state.source, on=False))
    ambient = state.scene.power_on_aperture(center, facing, diameter, dark)
    return max(total - ambient, 0.0), ambient


class LockInBinding:
    """The callable an :class:`Sr830Emulator` asks for its input (see :func:`bind_lockin`).

    Powers are cached per world state (positions, source, scene version), so polling the
    lock-in does not re-integrate the scene when nothing moved.
    """

    def __init__(self, emulator: Sr830Emulator, world_name: str,
                 photodiode: ChoppedPhotodiode) -> None:
        self.emulator = emulator
        self.world_name = world_name
        self.photodiode = photodiode
        self._cache: dict[tuple, Any] = {}  # a subclass caches its own readings
        self._lock = threading.Lock()

    def powers_w(self) -> tuple[float, float]:
        """(source-borne, ambient) power now; darkness while the world does not exist."""
        world = find_world(self.world_name)
        if world is None:
            return 0.0, 0.0
        key = (world.snapshot().key, world.power_meter, self.photodiode.aperture_diameter_mm)
        with self._lock:
            cached = self._cache.get(key)
        if cached is not None:
            return cached
        powers = split_power_w(world, self.photodiode.aperture_diameter_mm)
        with self._lock:
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = powers
        return powers

    def __call__(self) -> InputSignal:
        source_w, ambient_w = self.powers_w()
        return self.photodiode.signal(
            source_w, ambient_w, chopper_hz=self.emulator.reference_input_hz,
            amplifier_noise_v_per_rthz=self.emulator.input_noise_v_per_rthz,
        )


class ModulatedLockInBinding(LockInBinding):
    """The lock-in behind a photodiode lit through a PEM generator (no chopper).

    The world's polarisation state gives the generator's mean and its 1f and 2f parts
    (:class:`~hw_mocks.sim.polarisation.PolarisationState`); the detector's power is
    linear in the generator, so each part's power is the source-borne power with the
    generator replaced by that part (ambient light, which the PEM does not modulate,
    subtracted). The input the SR830 sees: the 1f term as the fundamental and the 2f term
    as harmonic 2, their signs as phases 0°/180° (RMS volts: the lock-in's convention and
    that of :func:`analysis.polarimetry.drr.pem_instrument_rows`), at the reference of the
    PEM controller, which drives REF IN (the emulator's ``reference_input_hz`` follows
    it). The photodiode's DC output (mean signal plus ambient) is wired to the lock-in's
    Aux In 1, where ``OAUX? 1`` reads it through the SR830's 16-bit converter (the
    emulator's :meth:`~hw_mocks.firmware.sr830.Sr830Emulator.aux_input_reading`): the DC
    channel in the same volts as 1f and 2f.
    """

    def harmonic_powers_w(self) -> tuple[float, float, float, float, float | None]:
        """(mean, 1f RMS, 2f RMS source-borne power, ambient power, modulation Hz)."""
        world = find_world(self.world_name)
        if world is None:
            return 0.0, 0.0, 0.0, 0.0, None
        state = world.snapshot()
        key = (state.key, world.power_meter, self.photodiode.aperture_diameter_mm, "pem")
        with self._lock:
            cached: tuple[float, float, float, float, float | None] | None = \
                self._cache.get(key)
        if cached is not None:
            return cached
        head = world.power_meter
        diameter = head.aperture_diameter_mm if self.photodiode.aperture_diameter_mm is None \
            else self.photodiode.aperture_diameter_mm
        center, facing = state.pose.detector_dir * head.distance_mm, -state.pose.detector_dir
        dark = replace(state, source=replace(state.source, on=False))
        ambient = state.scene.power_on_aperture(center, facing, diameter, dark)
        optics = state.optics
        if optics is None or not state.source.on:
            result: tuple[float, float, float, float, float | None] = (
                0.0, 0.0, 0.0, ambient, None if optics is None else optics.modulation_hz)
        else:
            def borne(generator: Any) -> float:
                probe = replace(state, optics=replace(optics, generator=generator))
                return state.scene.power_on_aperture(center, facing, diameter, probe) - ambient

            parts = dict(optics.harmonics)
            result = (max(borne(optics.generator), 0.0),
                      borne(parts[1]) if 1 in parts else 0.0,
                      borne(parts[2]) if 2 in parts else 0.0, ambient, optics.modulation_hz)
        with self._lock:
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = result
        return result

    def __call__(self) -> InputSignal:
        mean_w, first_w, second_w, ambient_w, frequency = self.harmonic_powers_w()
        pd = self.photodiode
        volts = pd.volts_per_watt
        if frequency:
            self.emulator.reference_input_hz = frequency
        dc_v = volts * (mean_w + ambient_w)
        self.emulator.aux_inputs_v[0] = dc_v
        mean_current_a = pd.responsivity_a_per_w * (mean_w + ambient_w)
        shot = pd.transimpedance_v_per_a * math.sqrt(2.0 * ELEMENTARY_CHARGE_C * mean_current_a)
        return InputSignal(
            ac_rms_v=volts * abs(first_w), phase_deg=0.0 if first_w >= 0 else 180.0,
            frequency_hz=None, dc_v=dc_v,
            noise_v_per_rthz=math.hypot(self.emulator.input_noise_v_per_rthz, shot),
            harmonics=((2, volts * abs(second_w), 0.0 if second_w >= 0 else 180.0),),
        )


def bind_lockin(emulator: Sr830Emulator, world: VirtualBench | str,
                photodiode: ChoppedPhotodiode | None = None, *,
                modulated: bool = False) -> LockInBinding:
    """Feed ``emulator`` the chopped photodiode signal at the detector of ``world``.

    ``world`` is a :class:`VirtualBench` or the name of one (looked up at each reading).
    ``modulated``: the photodiode sees the world's PEM generator instead of a chopped beam
    (:class:`ModulatedLockInBinding`). Returns the binding (also set as
    ``emulator.input_signal``).
    """
    name = world.name if isinstance(world, VirtualBench) else str(world)
    kind = ModulatedLockInBinding if modulated else LockInBinding
    binding = kind(emulator, name, photodiode or ChoppedPhotodiode())
    with emulator.lock:
        emulator.input_signal = binding
        emulator.bound_world = name
    return binding
