"""The dark readings of the point detectors (power meter, lock-in) of a run.

A photodiode reads its dark current, and ambient light, whether or not the beam is on: a
power meter's reading of a scattering point is ``P_s + D`` with ``D`` a few nW on the
simulated PM100 (2 nA of dark current), 15 % of a diffuser's signal near the normal and
half of it at grazing angles. The engine reads every detector with the light off as the
plan's ``[acquisition] dark`` says (the same policy as the camera's dark frames):

* ``"per_point"``: after each point's light readings (run-file columns ``power_dark_w``,
  ``lockin_dark_x_v``, ``lockin_dark_y_v``, ``lockin_dark_u_v``);
* ``"per_row"`` and ``"start"``: dark-labelled points (the first before every row of θi,
  or once before the scan): each scattering point uses the latest one before it (the
  first one after it when none came before).

This module finds the dark of every scattering point and what is known of its noise:

* **Power meter.** One reading has the meter's noise floor σ₀ (amplifier and shot noise of
  the dark current) plus a part proportional to the signal. σ₀ is *measured* as the
  standard deviation of the run's dark readings (at least three; their spread also holds
  any drift of the dark between points, so it is an upper bound); with fewer it is not
  known, and the caller falls back to its relative noise and says so. The dark of a
  point is subtracted with σ₀; a dark shared between points (``start``, ``per_row``) is
  one error for all of them: a covariance, not independent noise (GUM JCGM 100:2008
  §5.2, correlated input quantities).
* **Lock-in.** The dark is a vector in (X, Y): a coherent offset at the reference
  frequency (pickup from the chopper drive) adds to the signal's phasor. The net signal
  is |(X − X_d, Y − Y_d)| with the standard error of the dark's components added in
  quadrature (Stanford Research SR830 manual Rev. 2.5, p. 3-13, "Dynamic reserve",
  on coherent pickup).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from instrument.run.layout import STATUS_OK
from instrument.run.runfile import RunData

__all__ = ["PointDark", "lockin_dark", "net_lockin_r", "power_meter_dark"]

#: Dark readings needed to measure the noise floor from their spread.
MIN_DARKS_FOR_NOISE = 3


@dataclass(frozen=True)
class PointDark:
    """The dark of each scattering point of a detector.

    Attributes
    ----------
    level : ndarray, shape (n,)
        The dark reading subtracted from each point (0 where none was measured); for the
        lock-in, its X and Y are ``level_x``, ``level_y``.
    u_level : ndarray, shape (n,)
        Standard uncertainty of that dark reading (0 where none).
    group : ndarray of int, shape (n,)
        Which dark reading each point used (points sharing one share its error); −1:
        none, or a dark of its own.
    noise_floor : float or None
        The detector's reading noise measured from the spread of the dark readings
        (None: fewer than :data:`MIN_DARKS_FOR_NOISE` readings).
    policy : str
        ``"per_point"``, ``"dark points"`` (``start`` or ``per_row``) or ``"none"``.
    n_readings : int
        Dark readings the run holds.
    """

    level: np.ndarray
    u_level: np.ndarray
    group: np.ndarray
    noise_floor: float | None
    policy: str
    n_readings: int
    level_x: np.ndarray | None = None
    level_y: np.ndarray | None = None

    @property
    def measured(self) -> bool:
        return self.policy != "none"

    def shared_covariance(self, u_level: np.ndarray | None = None) -> np.ndarray:
        """Covariance (detector units²) of the subtracted darks between points: the
        variance of a shared dark for every pair of points that used it (``u_level``: the
        darks' σ, default :attr:`u_level`)."""
        u = self.u_level if u_level is None else np.asarray(u_level, dtype=float)
        n = self.group.size
        cov = np.zeros((n, n))
        for g in np.unique(self.group[self.group >= 0]):
            members = np.flatnonzero(self.group == g)
            cov[np.ix_(members, members)] = u[members[0]] ** 2
        return cov

    def describe(self, unit: str, scale: float) -> str:
        """One line for the provenance: what was subtracted and its noise."""
        if not self.measured:
            return "none measured (the plan's [acquisition] dark is \"none\")"
        floor = ("noise floor not measured (fewer than "
                 f"{MIN_DARKS_FOR_NOISE} dark readings)" if self.noise_floor is None
                 else f"noise floor {self.noise_floor * scale:.3g} {unit} from their spread")
        return (f"{self.policy}: {self.n_readings} dark reading(s), mean "
                f"{float(np.mean(self.level)) * scale:.4g} {unit}; {floor}")


def _dark_rows(run: RunData) -> np.ndarray:
    return np.flatnonzero((run.label == "dark") & (run.point_status == STATUS_OK))


def _nearest_before(rows: np.ndarray, darks: np.ndarray) -> np.ndarray:
    """For each row, the latest dark row before it (the first after it if none)."""
    k = np.searchsorted(darks, rows) - 1
    return darks[np.maximum(k, 0)]


def _spread(values: np.ndarray) -> float | None:
    v = values[np.isfinite(values)]
    return float(np.std(v, ddof=1)) if v.size >= MIN_DARKS_FOR_NOISE else None


def power_meter_dark(run: RunData, rows: np.ndarray) -> PointDark:
    """The power meter's dark for the scattering points ``rows`` (module docstring)."""
    n = rows.size
    own = run.power_dark_w
    if own is not None and np.all(np.isfinite(own[rows])):
        darks = own[np.isfinite(own)]
        floor = _spread(darks)
        level = own[rows].astype(float)
        return PointDark(level, np.full(n, floor or 0.0), np.full(n, -1), floor,
                         "per_point", int(darks.size))
    drows = _dark_rows(run)
    drows = drows[np.isfinite(run.power_w[drows])]
    if drows.size == 0:
        return PointDark(np.zeros(n), np.zeros(n), np.full(n, -1), None, "none", 0)
    floor = _spread(run.power_w[drows])
    used = _nearest_before(rows, drows)
    return PointDark(run.power_w[used].astype(float), np.full(n, floor or 0.0), used, floor,
                     "dark points", int(drows.size))


def lockin_dark(run: RunData, rows: np.ndarray) -> PointDark:
    """The lock-in's dark (X, Y) for the scattering points ``rows`` (module docstring);
    ``noise_floor`` is the typical standard error of one dark component."""
    n = rows.size
    x, y, u = run.lockin_dark_x_v, run.lockin_dark_y_v, run.lockin_dark_u_v
    if x is not None and y is not None and np.all(np.isfinite(x[rows])):
        uu = u[rows].astype(float) if u is not None else np.zeros(n)
        return PointDark(np.hypot(x[rows], y[rows]), uu, np.full(n, -1),
                         float(np.median(uu)), "per_point", int(np.isfinite(x).sum()),
                         level_x=x[rows].astype(float), level_y=y[rows].astype(float))
    lx, ly = run.lockin_x_v, run.lockin_y_v
    drows = _dark_rows(run)
    if lx is not None and ly is not None:
        drows = drows[np.isfinite(lx[drows]) & np.isfinite(ly[drows])]
    else:
        drows = drows[:0]
    if drows.size == 0:
        return PointDark(np.zeros(n), np.zeros(n), np.full(n, -1), None, "none", 0,
                         level_x=np.zeros(n), level_y=np.zeros(n))
    used = _nearest_before(rows, drows)
    # a dark point's own standard error: that of R from its snapshots (R ≈ the noise there,
    # so its standard error stands for a component's)
    ur = run.lockin_u_r_v
    uu = ur[used].astype(float) if ur is not None else np.zeros(n)
    return PointDark(np.hypot(lx[used], ly[used]), uu, used,
                     float(np.median(uu)) if uu.size else None, "dark points",
                     int(drows.size), level_x=lx[used].astype(float),
                     level_y=ly[used].astype(float))


def net_lockin_r(x: np.ndarray, y: np.ndarray, u_r: np.ndarray, dark: PointDark
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(R, σ_R) of the light less the dark phasor: R = |(X − X_d, Y − Y_d)| and σ_R² =
    u_r² + u_d² (the dark's component error along the signal's phase)."""
    assert dark.level_x is not None and dark.level_y is not None
    r = np.hypot(x - dark.level_x, y - dark.level_y)
    return r, np.hypot(u_r, dark.u_level)
