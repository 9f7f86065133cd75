"""The common BRDF model interface and the sum of models.

Every model is a :class:`BRDFModel`: a frozen description (name, parameters with units,
bounds, start values and which ones are fitted in log space) plus two pure functions of a
parameter vector and a precomputed :class:`~analysis.brdf.geometry.Geometry`: the value
(shape S, unit 1/sr unless the model says otherwise) and, where available, the analytic
Jacobian (shape S + (k,)). Angle conventions are those of :mod:`analysis.brdf.geometry`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import Geometry, make_geometry

ValueFn = Callable[[NDArray[np.float64], Geometry], NDArray[np.float64]]
JacFn = Callable[[NDArray[np.float64], Geometry], NDArray[np.float64]]


@dataclass(frozen=True)
class ParamSpec:
    """One model parameter.

    Attributes
    ----------
    name : str
        Identifier (unique within a model).
    unit : str
        Physical unit ("1" for dimensionless, "rad", "µm", ...).
    lower, upper : float
        Bounds used by fitting (``upper`` may be ``inf``).
    start : float
        Default starting value.
    log : bool
        Fit in log space (widths, exponents, scales spanning decades); requires lower > 0.
    description : str
        What it means physically.
    """

    name: str
    unit: str
    lower: float
    upper: float
    start: float
    log: bool = False
    description: str = ""

    def __post_init__(self) -> None:
        if not self.lower <= self.start <= self.upper:
            raise ValueError(f"start of {self.name} outside its bounds")
        if self.log and self.lower <= 0:
            raise ValueError(f"log-parameterised {self.name} needs a positive lower bound")


@dataclass(frozen=True)
class BRDFModel:
    """A BRDF model with a vectorised evaluation and optional analytic Jacobian.

    Attributes
    ----------
    name : str
        Registry name (composites join their parts with "+").
    params : tuple of ParamSpec
        The parameters, in the order of the parameter vector.
    value_fn : callable
        ``value_fn(p, geometry) -> ndarray`` of the geometry's shape.
    jac_fn : callable or None
        ``jac_fn(p, geometry) -> ndarray`` of shape S + (k,): ∂f/∂p_j in natural units; it
        must return a new array (callers may modify it in place).
    energy_bounded : bool
        Whether the model promises DHR ≤ 1 for parameters in its physical range (stated in
        ``validity``).
    reciprocal : bool
        Whether f(ωi, ωr) = f(ωr, ωi) holds exactly for all parameters.
    unit : str
        Unit of the returned value ("1/sr"; "1/rad" for flatland models).
    description, validity, reference : str
        Documentation carried with the model (shown in reports).
    """

    name: str
    params: tuple[ParamSpec, ...]
    value_fn: ValueFn
    jac_fn: JacFn | None = None
    energy_bounded: bool = True
    reciprocal: bool = True
    unit: str = "1/sr"
    description: str = ""
    validity: str = ""
    reference: str = ""

    # ------------------------------------------------------------------ properties
    @property
    def n_params(self) -> int:
        return len(self.params)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(p.unit for p in self.params)

    @property
    def lower(self) -> NDArray[np.float64]:
        return np.array([p.lower for p in self.params], dtype=float)

    @property
    def upper(self) -> NDArray[np.float64]:
        return np.array([p.upper for p in self.params], dtype=float)

    @property
    def start(self) -> NDArray[np.float64]:
        return np.array([p.start for p in self.params], dtype=float)

    @property
    def log_mask(self) -> NDArray[np.bool_]:
        return np.array([p.log for p in self.params], dtype=bool)

    @property
    def has_analytic_jacobian(self) -> bool:
        return self.jac_fn is not None

    # ------------------------------------------------------------------ evaluation
    def _check(self, params: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(params, dtype=float).reshape(-1)
        if p.size != self.n_params:
            raise ValueError(
                f"{self.name} takes {self.n_params} parameters {self.param_names}, got {p.size}"
            )
        return p

    def evaluate(
        self,
        params: ArrayLike,
        theta_i: ArrayLike,
        phi_i: ArrayLike,
        theta_r: ArrayLike,
        phi_r: ArrayLike,
    ) -> NDArray[np.float64]:
        """BRDF at angles in radians (conventions of :mod:`analysis.brdf.geometry`).

        Parameters
        ----------
        params : array_like, shape (k,)
            Parameter vector in the order of :attr:`param_names`, natural units.
        theta_i, phi_i, theta_r, phi_r : array_like
            Broadcast together to shape S.

        Returns
        -------
        ndarray, shape S
        """
        return self.evaluate_geometry(params, make_geometry(theta_i, phi_i, theta_r, phi_r))

    def evaluate_geometry(self, params: ArrayLike, geometry: Geometry) -> NDArray[np.float64]:
        """BRDF on a precomputed geometry, shape ``geometry.shape``."""
        return np.asarray(self.value_fn(self._check(params), geometry), dtype=float)

    def jacobian_geometry(
        self, params: ArrayLike, geometry: Geometry, *, rel_step: float = 1e-6
    ) -> NDArray[np.float64]:
        """∂f/∂p, shape ``geometry.shape + (k,)``: analytic where the model has it,
        otherwise central differences with step ``rel_step·max(|p|, 1e-3)``."""
        p = self._check(params)
        if self.jac_fn is not None:
            return np.asarray(self.jac_fn(p, geometry), dtype=float)
        return numeric_jacobian(self.value_fn, p, geometry, rel_step=rel_step)

    def with_start(self, start: Sequence[float]) -> BRDFModel:
        """A copy with other default start values."""
        s = self._check(start)
        return replace(
            self,
            params=tuple(
                replace(ps, start=float(v)) for ps, v in zip(self.params, s, strict=True)
            ),
        )

    def __add__(self, other: BRDFModel) -> BRDFModel:
        return sum_models(self, other)


def numeric_jacobian(
    value_fn: ValueFn, p: NDArray[np.float64], geometry: Geometry, *, rel_step: float = 1e-6
) -> NDArray[np.float64]:
    """Central-difference Jacobian of ``value_fn`` on a fixed geometry, shape S + (k,)."""
    cols = []
    for j in range(p.size):
        h = rel_step * max(abs(p[j]), 1e-3)
        up = p.copy()
        dn = p.copy()
        up[j] += h
        dn[j] -= h
        cols.append((value_fn(up, geometry) - value_fn(dn, geometry)) / (2.0 * h))
    return np.stack(cols, axis=-1)


def sum_models(*models: BRDFModel) -> BRDFModel:
    """The sum f = Σ f_m of models (e.g. Lambertian + Cook–Torrance GGX).

    Parameter names become ``"<component>.<param>"``; a component name that repeats gets a
    numeric suffix ("ggx", "ggx2"). The Jacobian is analytic for the parts that have one
    and central differences of the part alone for the others. The sum is
    energy bounded only as the sum of the parts' bounds (e.g. ρd + ks ≤ 1 keeps
    Lambertian + microfacet ≤ 1) — stated in ``validity``.
    """
    if not models:
        raise ValueError("sum_models needs at least one model")
    parts: list[BRDFModel] = []
    for m in models:
        parts.extend(m.parts if isinstance(m, CompositeModel) else [m])
    labels: list[str] = []
    for m in parts:
        base = m.name
        label = base
        i = 2
        while label in labels:
            label = f"{base}{i}"
            i += 1
        labels.append(label)
    specs: list[ParamSpec] = []
    slices: list[slice] = []
    for label, m in zip(labels, parts, strict=True):
        start = len(specs)
        specs.extend(replace(ps, name=f"{label}.{ps.name}") for ps in m.params)
        slices.append(slice(start, len(specs)))
    units = {m.unit for m in parts}
    if len(units) != 1:
        raise ValueError(f"cannot add models with different units {sorted(units)}")

    def value(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
        total = np.array(parts[0].value_fn(p[slices[0]], g), dtype=float, copy=True)
        for m, sl in zip(parts[1:], slices[1:], strict=True):
            total += m.value_fn(p[sl], g)
        return total

    jac: JacFn | None = None
    if any(m.jac_fn is not None for m in parts):
        # analytic where a part has it, central differences of that part alone where not
        # (a sum's columns are its parts' columns: no need to difference the whole sum)

        def part_jac(m: BRDFModel, q: NDArray[np.float64], g: Geometry) -> NDArray[Any]:
            if m.jac_fn is not None:
                return m.jac_fn(q, g)
            return numeric_jacobian(m.value_fn, q, g)

        def jac(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
            cols = [part_jac(m, p[sl], g) for m, sl in zip(parts, slices, strict=True)]
            return np.concatenate(cols, axis=-1)

    return CompositeModel(
        name="+".join(m.name for m in parts),
        params=tuple(specs),
        value_fn=value,
        jac_fn=jac,
        energy_bounded=all(m.energy_bounded for m in parts),
        reciprocal=all(m.reciprocal for m in parts),
        unit=units.pop(),
        description="Sum of " + ", ".join(m.name for m in parts),
        validity="energy bounded when the sum of the parts' albedo scales is ≤ 1; "
        + "; ".join(f"{m.name}: {m.validity}" for m in parts if m.validity),
        reference="; ".join(m.reference for m in parts if m.reference),
        parts=tuple(parts),
    )


@dataclass(frozen=True)
class CompositeModel(BRDFModel):
    """A :class:`BRDFModel` that is a sum of parts (kept for reporting per component)."""

    parts: tuple[BRDFModel, ...] = ()

    def component_values(
        self, params: ArrayLike, geometry: Geometry
    ) -> dict[str, NDArray[np.float64]]:
        """Each part's contribution on ``geometry``, keyed by part name (in order)."""
        p = self._check(params)
        out: dict[str, NDArray[np.float64]] = {}
        i = 0
        for m in self.parts:
            key = m.name if m.name not in out else f"{m.name}{len(out) + 1}"
            out[key] = m.value_fn(p[i : i + m.n_params], geometry)
            i += m.n_params
        return out
