"""One PEM polarimeter setting's readings: the photodiode's DC on the lock-in's Aux In 1 and
the 1f and 2f terms by detection harmonic (ADR 0106).

Per harmonic (1, then 2) the lock-in's ``HARM`` is set, its output filter settles for the
plan's ``time_constants`` × τ (the 99 % wait leaves 1 % of the 1f–2f step, a 10⁻³ bias of
the reduced matrix: ADR 0105), the range is chosen for that harmonic (1f and 2f differ by
up to ten times) and ``reads`` snapshots are taken one settling wait apart. The harmonic
is restored to 1 afterwards, also on an error. The range choice and the snapshots are the
engine's lock-in readings (an overload re-ranges and reads again; one that persists raises
:class:`~drivers.errors.ControllerError`, which the device's retry policy handles).

σ of each channel (volts):

* 1f, 2f: the standard error of the in-phase outputs X over the snapshots, at least
  :data:`OUTPUT_FLOOR` × the full scale (the outputs' resolution, and the modulator drive's
  six-digit rounding, which no scatter of snapshots shows); the fit pools these spreads
  into the run's noise model (:mod:`instrument.pipelines.polarimetry.pem_readings`);
* DC: the standard error of ``reads`` Aux In readings combined with the Aux In's
  quantisation, 1/3 mV (SR830 manual, specifications: Aux inputs 16-bit, ±10.5 V) over √12
  — an error a mean of quantised readings does not average away.

The reference is the modulator's REF OUT at the lock-in's own phase setting; each
harmonic's mean phase θ is recorded with it (a signal in phase reads Y ≈ 0, and the
reduction uses the signed X).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

__all__ = ["AUX_RESOLUTION_V", "OUTPUT_FLOOR", "HarmonicLockIn", "read_pem"]

#: The SR830's Aux In resolution (V): 16 bits over ±10.5 V (the manual's "1/3 mV").
AUX_RESOLUTION_V = 21.0 / 2**16
#: The smallest σ of a harmonic's X, as a fraction of the full scale it was read at.
OUTPUT_FLOOR = 1e-5


class HarmonicLockIn(Protocol):
    """What a PEM reading needs of a lock-in (the SR830 driver has it)."""

    name: str
    harmonic: int
    sensitivity_v: float
    time_constant_s: float

    def settle(self, n_time_constants: float | None = None, *,
               timeout: float = 60.0) -> float: ...

    def read_aux_input(self, channel: int = 1) -> float: ...


def _harmonic(li: HarmonicLockIn, n: int, time_constants: float,
              snapshots: Callable[[], list[Any]]) -> dict[str, float]:
    li.harmonic = n
    li.settle(time_constants, timeout=max(60.0, 2 * time_constants * float(li.time_constant_s)))
    snaps = snapshots()
    x = np.array([s.x_v for s in snaps])
    fs = float(li.sensitivity_v)
    return {f"pem_{n}f_v": float(x.mean()),
            f"pem_u_{n}f_v": max(float(x.std(ddof=1) / math.sqrt(x.size)), OUTPUT_FLOOR * fs),
            f"pem_{n}f_y_v": float(np.mean([s.y_v for s in snaps])),
            f"pem_{n}f_theta_deg": float(np.mean([s.theta_deg for s in snaps])),
            f"pem_{n}f_sensitivity_v": fs}


def read_pem(li: HarmonicLockIn, *, time_constants: float, reads: int,
             snapshots: Callable[[], list[Any]]) -> dict[str, float]:
    """DC, 1f and 2f of the present setting with their σ (module docstring), as run-file
    columns (:data:`~instrument.run.layout.PEM_FIELDS`; the modulator's are the engine's).
    ``snapshots`` takes one harmonic's readings once its settle is over: the engine's
    range choice and overload handling, ``reads`` snapshots one settling wait apart."""
    reads = max(int(reads), 2)
    out = {"pem_time_constants": float(time_constants)}
    try:
        for n in (1, 2):
            out.update(_harmonic(li, n, time_constants, snapshots))
    finally:
        if li.harmonic != 1:
            li.harmonic = 1
    # the DC after the harmonics' waits: the photodiode has settled to the new setting
    dc = np.array([li.read_aux_input(1) for _ in range(reads)])
    out.update({"pem_dc_v": float(dc.mean()),
                "pem_u_dc_v": math.hypot(float(dc.std(ddof=1) / math.sqrt(dc.size)),
                                         AUX_RESOLUTION_V / math.sqrt(12.0))})
    return out
