"""Light-field data types with explicit sampling grids and units.

2-D (flatland) light field ``L(y, θ)``: radiance on a plane at axial position ``z_mm``,
transverse position ``y`` in mm and ray angle ``θ`` in rad measured from the +z axis
(``tan θ = dy/dz``), as in Sasaki 2020 (ch. 1–2).  The angle grid is the cell-centred
grid of a stated domain ``[a, b] ⊂ (−π/2, π/2)``: ``θ_j = a + (j + ½)(b − a)/N_θ``, so the
discrete Fourier basis of the domain (eq. 2-13) is sampled exactly.

4-D light field ``L(x, y, u, v)``: positions x, y in mm and the two ray angles u = θ_x,
v = θ_y in rad on cell-centred grids of their domains (same conventions per axis).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["LightField2D", "LightField4D", "theta_grid", "uniform_grid"]

_RTOL = 1e-9


def theta_grid(domain_rad: tuple[float, float], n: int) -> NDArray[np.float64]:
    """Cell-centred angle grid ``a + (j + ½)(b − a)/n`` on ``[a, b] ⊂ (−π/2, π/2)``."""
    a, b = float(domain_rad[0]), float(domain_rad[1])
    _check_domain(a, b)
    if n < 1:
        raise ValueError("n must be >= 1")
    return a + (np.arange(n) + 0.5) * (b - a) / n


def uniform_grid(start_mm: float, stop_mm: float, n: int) -> NDArray[np.float64]:
    """``n`` equally spaced positions from start to stop inclusive (mm)."""
    if n < 2:
        raise ValueError("n must be >= 2")
    return np.linspace(float(start_mm), float(stop_mm), n)


def _check_domain(a: float, b: float) -> None:
    if not (-np.pi / 2 < a < b < np.pi / 2):
        raise ValueError(f"angle domain [{a}, {b}] must satisfy -π/2 < a < b < π/2")


def _check_uniform(x: NDArray[np.float64], name: str) -> float:
    if x.ndim != 1 or x.size < 2:
        raise ValueError(f"{name} must be 1-D with at least 2 samples")
    d = np.diff(x)
    step = float(d.mean())
    if step <= 0 or not np.allclose(d, step, rtol=1e-6, atol=0):
        raise ValueError(f"{name} must be strictly increasing and uniform")
    return step


def _check_theta(theta: NDArray[np.float64], domain: tuple[float, float], name: str) -> None:
    a, b = domain
    _check_domain(a, b)
    expected = theta_grid(domain, theta.size)
    if not np.allclose(theta, expected, rtol=0, atol=_RTOL * (b - a) + 1e-12):
        raise ValueError(f"{name} must be the cell-centred grid of its domain [{a}, {b}]")


def _frozen(a: NDArray[Any]) -> NDArray[Any]:
    out = np.array(a, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class LightField2D:
    """Flatland light field ``L(y, θ)`` on a regular grid.

    Parameters
    ----------
    radiance : ndarray of shape (N_y, N_θ)
        Radiance samples (any consistent radiance unit; complex allowed for spectra).
    y_mm : ndarray of shape (N_y,)
        Uniform, increasing transverse positions in mm.
    theta_rad : ndarray of shape (N_θ,)
        The cell-centred grid of ``domain_rad`` (see :func:`theta_grid`).
    domain_rad : (float, float)
        The angle domain ``[a, b] ⊂ (−π/2, π/2)``.
    z_mm : float
        Axial position of the plane (mm); bookkeeping for propagation.

    Arrays are copied and made read-only, so a field never changes after creation.
    """

    radiance: NDArray[Any]
    y_mm: NDArray[np.float64]
    theta_rad: NDArray[np.float64]
    domain_rad: tuple[float, float]
    z_mm: float = 0.0
    _dy: float = field(init=False, repr=False, compare=False, default=0.0)

    def __post_init__(self) -> None:
        rad = np.asarray(self.radiance)
        y = np.asarray(self.y_mm, dtype=float)
        th = np.asarray(self.theta_rad, dtype=float)
        dom = (float(self.domain_rad[0]), float(self.domain_rad[1]))
        if rad.shape != (y.size, th.size):
            raise ValueError(f"radiance shape {rad.shape} != (N_y, N_θ) = {(y.size, th.size)}")
        dy = _check_uniform(y, "y_mm")
        _check_theta(th, dom, "theta_rad")
        object.__setattr__(self, "radiance", _frozen(rad))
        object.__setattr__(self, "y_mm", _frozen(y))
        object.__setattr__(self, "theta_rad", _frozen(th))
        object.__setattr__(self, "domain_rad", dom)
        object.__setattr__(self, "z_mm", float(self.z_mm))
        object.__setattr__(self, "_dy", dy)

    @property
    def dy_mm(self) -> float:
        """Transverse sample spacing (mm)."""
        return self._dy

    @property
    def dtheta_rad(self) -> float:
        """Angular sample spacing (rad), ``(b − a)/N_θ``."""
        return (self.domain_rad[1] - self.domain_rad[0]) / self.theta_rad.size

    @property
    def shape(self) -> tuple[int, int]:
        """(N_y, N_θ)."""
        return self.radiance.shape

    def with_radiance(self, radiance: NDArray[Any], *, z_mm: float | None = None) -> LightField2D:
        """A field on the same grids with new samples (and optionally a new plane z)."""
        return LightField2D(
            radiance, self.y_mm, self.theta_rad, self.domain_rad,
            self.z_mm if z_mm is None else z_mm,
        )

    @classmethod
    def from_function(
        cls,
        func: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[Any]],
        y_mm: NDArray[np.float64],
        domain_rad: tuple[float, float],
        n_theta: int,
        *,
        z_mm: float = 0.0,
    ) -> LightField2D:
        """Sample ``func(y_mm[:, None], theta_rad[None, :])`` on the grids."""
        th = theta_grid(domain_rad, n_theta)
        y = np.asarray(y_mm, dtype=float)
        vals = np.asarray(func(y[:, None], th[None, :]))
        return cls(np.broadcast_to(vals, (y.size, th.size)), y, th, domain_rad, z_mm)


@dataclass(frozen=True)
class LightField4D:
    """Light field ``L(x, y, u, v)``: positions (mm) and ray angles u = θ_x, v = θ_y (rad).

    Parameters
    ----------
    radiance : ndarray of shape (N_x, N_y, N_u, N_v)
    x_mm, y_mm : uniform position grids (mm)
    u_rad, v_rad : cell-centred angle grids of ``u_domain_rad`` and ``v_domain_rad``
    u_domain_rad, v_domain_rad : angle domains inside (−π/2, π/2)
    z_mm : axial position of the plane (mm)
    """

    radiance: NDArray[Any]
    x_mm: NDArray[np.float64]
    y_mm: NDArray[np.float64]
    u_rad: NDArray[np.float64]
    v_rad: NDArray[np.float64]
    u_domain_rad: tuple[float, float]
    v_domain_rad: tuple[float, float]
    z_mm: float = 0.0

    def __post_init__(self) -> None:
        rad = np.asarray(self.radiance)
        x = np.asarray(self.x_mm, dtype=float)
        y = np.asarray(self.y_mm, dtype=float)
        u = np.asarray(self.u_rad, dtype=float)
        v = np.asarray(self.v_rad, dtype=float)
        ud = (float(self.u_domain_rad[0]), float(self.u_domain_rad[1]))
        vd = (float(self.v_domain_rad[0]), float(self.v_domain_rad[1]))
        if rad.shape != (x.size, y.size, u.size, v.size):
            raise ValueError(f"radiance shape {rad.shape} does not match the grids")
        _check_uniform(x, "x_mm")
        _check_uniform(y, "y_mm")
        _check_theta(u, ud, "u_rad")
        _check_theta(v, vd, "v_rad")
        for name, val in (("radiance", rad), ("x_mm", x), ("y_mm", y), ("u_rad", u),
                          ("v_rad", v)):
            object.__setattr__(self, name, _frozen(val))
        object.__setattr__(self, "u_domain_rad", ud)
        object.__setattr__(self, "v_domain_rad", vd)
        object.__setattr__(self, "z_mm", float(self.z_mm))

    @property
    def dx_mm(self) -> float:
        """Sample spacing along x (mm)."""
        return float(self.x_mm[1] - self.x_mm[0])

    @property
    def dy_mm(self) -> float:
        """Sample spacing along y (mm)."""
        return float(self.y_mm[1] - self.y_mm[0])

    @property
    def du_rad(self) -> float:
        """Angular spacing along u (rad)."""
        return (self.u_domain_rad[1] - self.u_domain_rad[0]) / self.u_rad.size

    @property
    def dv_rad(self) -> float:
        """Angular spacing along v (rad)."""
        return (self.v_domain_rad[1] - self.v_domain_rad[0]) / self.v_rad.size

    def with_radiance(self, radiance: NDArray[Any], *, z_mm: float | None = None) -> LightField4D:
        """A field on the same grids with new samples (and optionally a new plane z)."""
        return LightField4D(
            radiance, self.x_mm, self.y_mm, self.u_rad, self.v_rad,
            self.u_domain_rad, self.v_domain_rad, self.z_mm if z_mm is None else z_mm,
        )
