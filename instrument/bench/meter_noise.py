"""How noisy one power-meter reading is, from what the bench knows.

A reading's σ has two parts: a floor that does not depend on the light (the photodiode's
dark-current noise and the amplifier's), which the reduction measures from the spread of
the dark readings (:mod:`instrument.pipelines.brdf.dark`), and a part proportional to the
reading (the relative noise: source fluctuations seen by the head, the meter's range
amplifier), which darks cannot show. The relative part comes, in order, from

1. the profile: ``relative_noise`` of the power meter's device table (1σ as a fraction of
   one reading, from the head's and meter's datasheet or measured by repeated readings of
   a steady beam);
2. the emulated PM100USB (``simusb://`` URLs): its documented noise model, 10⁻⁴ of the
   photocurrent per sample (``hw_mocks/firmware/pm100usb.py``), divided by √n for the
   ``averaging`` count n of its settings, as the meter averages n samples per reading;
3. otherwise unknown: :data:`ASSUMED_RELATIVE_NOISE` is taken and every fit says so,
   naming the key to set.

The floor, when the run's darks are too few to measure it, is the profile's
``noise_floor_w`` (W, 1σ of one reading with the light off) if it declares one.

The relative noise is what matters at a glossy sample's high readings: with 0.5 % assumed
where the meter had 0.01 %, the χ² of such fits was far too small (BENCHMARKS.md,
honest_sigma).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["ASSUMED_RELATIVE_NOISE", "EMULATED_PM100_RELATIVE_NOISE", "MeterNoise",
           "meter_noise"]

#: Relative noise of one reading when nothing says otherwise (a conservative figure for a
#: photodiode head on a handheld meter; stated in the fit's warnings).
ASSUMED_RELATIVE_NOISE = 0.005
#: The emulated PM100USB's relative noise per sample (its documented measurement model).
EMULATED_PM100_RELATIVE_NOISE = 1.0e-4


@dataclass(frozen=True)
class MeterNoise:
    """The relative noise of one reading, where it came from, and a warning when it was
    assumed."""

    relative: float
    source: str
    warning: str | None = None
    #: The light-independent floor of one reading (W) the profile declares
    #: (``noise_floor_w``), for runs whose darks are too few to measure it; None: unknown.
    floor_w: float | None = None


def meter_noise(profile: Mapping[str, Any], role: str = "power_meter") -> MeterNoise:
    """The relative noise of one reading of the power meter ``role`` of the bench profile
    ``profile`` (the parsed TOML stored with a run; module docstring)."""
    dev = dict(dict(profile.get("devices", {})).get(role, {}))
    floor = dev.get("noise_floor_w")
    floor = None if floor is None else float(floor)
    if "relative_noise" in dev:
        rel = float(dev["relative_noise"])
        if not (rel >= 0 and math.isfinite(rel)):
            raise ValueError(f"devices.{role}.relative_noise must be a fraction ≥ 0, "
                             f"not {dev['relative_noise']!r}")
        return MeterNoise(rel, f"{rel:.2g} of the reading (profile)", floor_w=floor)
    if str(dev.get("url", "")).startswith("simusb://"):
        n = int(dict(dev.get("settings", {})).get("averaging", 1))
        rel = EMULATED_PM100_RELATIVE_NOISE / math.sqrt(max(n, 1))
        return MeterNoise(rel, f"{rel:.2g} of the reading (the emulated PM100USB's noise "
                               f"model, {n} sample(s) averaged)", floor_w=floor)
    return MeterNoise(
        ASSUMED_RELATIVE_NOISE, f"{ASSUMED_RELATIVE_NOISE:.2g} of the reading (assumed)",
        f"{role}: the relative noise of one reading is not declared, "
        f"{ASSUMED_RELATIVE_NOISE:.1%} is assumed; set devices.{role}.relative_noise (1σ as "
        "a fraction of a reading, from the head's datasheet or the spread of repeated "
        "readings of a steady beam)", floor_w=floor)
