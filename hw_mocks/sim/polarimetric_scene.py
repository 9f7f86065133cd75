"""The goniometer scene with Stokes vectors: a polarised source, a train, a Mueller sample.

The detectors of the virtual bench read intensity: the first Stokes component after the
polarisation-state analyser (PSA). With the generator's Stokes vector g (per unit source
power, in the incident beam's basis) and the analyser's first row a (in the scattered
beam's basis; :class:`~hw_mocks.sim.polarisation.PolarisationState`), a sample of
Mueller BRDF F(ωi, ωr) sends the detector what a scalar sample of BRDF

    f(ωi, ωr) = a · F(ωi, ωr) · g                                         (1/sr)

would. Every ray gets its own directions and bases, so this scene hands that scalar BRDF
to the goniometer scene (:mod:`hw_mocks.sim.goniometer_scene`), which does the beam,
footprint and aperture integrals as for any sample. A transmissive reference (air, a
polariser, a retarder at the sample position) leaves no sample in the beam: the direct
beam reaches the detector arm at 180° scaled by a · M_ref · g.

Without optics in the world (no ``[simulation.optics]``) g and a are (1, 0, 0, 0) and the
scene renders m00, the unpolarised BRDF.

The polarimetric scene has no veil: ambient light and the instrument signature would
need their own polarisation; ``from_config`` refuses them.

Configuration (``[simulation.scene]`` with ``kind = "polarimetric"``): ``sample``
(``"pbrdf"``, the default, with a ``[simulation.scene.pbrdf]`` table of
:class:`~hw_mocks.sim.polarised_sample.MicrofacetPolarisedSample`; or a reference
``"air"``, ``"polariser"``, ``"retarder"`` with a table of the same name), plus
``sample_radius_mm``, ``spot_samples`` and ``aperture_samples`` of the goniometer scene.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hw_mocks.sim.goniometer_scene import GoniometerScene
from hw_mocks.sim.polarisation import PolarisationState
from hw_mocks.sim.polarised_sample import MicrofacetPolarisedSample, reference_mueller
from hw_mocks.sim.state import WorldState

__all__ = ["PolarimetricScene"]

_UNPOLARISED = np.array([1.0, 0.0, 0.0, 0.0])
_LAB_UP = np.array([0.0, 1.0, 0.0])


def _effective_brdf(sample: MicrofacetPolarisedSample, state: WorldState) -> Any:
    """The scalar BRDF a · F · g of the sample under the optics of ``state``, with the
    call forms the goniometer scene uses (angles, and sample-frame components)."""
    g, a = _generator_analyser(state)
    up = state.pose.to_sample(_LAB_UP)

    def from_components(omega_i: Any, rx: Any, ry: Any, rz: Any) -> NDArray[np.float64]:
        wi = np.asarray(omega_i, dtype=float)
        wi = wi / np.linalg.norm(wi)
        wr = np.stack(np.broadcast_arrays(rx, ry, rz), axis=-1)
        return sample.intensity(wi, wr, up, a, g)

    def brdf(theta_i: Any, phi_i: Any, theta_r: Any, phi_r: Any) -> NDArray[np.float64]:
        ti, pi = float(theta_i), float(phi_i)
        wi = np.array([math.sin(ti) * math.cos(pi), math.sin(ti) * math.sin(pi), math.cos(ti)])
        st = np.sin(theta_r)
        return from_components(wi, st * np.cos(phi_r), st * np.sin(phi_r), np.cos(theta_r))

    # the call form the goniometer scene prefers, set on the function object
    brdf.from_components = from_components  # type: ignore[attr-defined]
    return brdf


def _generator_analyser(state: WorldState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    optics = state.optics
    if optics is None:
        return _UNPOLARISED, _UNPOLARISED
    return np.asarray(optics.generator), np.asarray(optics.analyser)


@dataclass(frozen=True)
class PolarimetricScene:
    """A Mueller-matrix sample (or a transmissive reference) in the goniometer scene.

    Attributes
    ----------
    sample : MicrofacetPolarisedSample or None
        The sample's pBRDF; None with a transmissive ``reference``.
    reference : ndarray (4, 4) or None
        Mueller matrix of a transmissive reference at the sample position.
    base : GoniometerScene
        Geometry and quadrature (its ``brdf`` and ``target`` are replaced per snapshot).
    """

    sample: MicrofacetPolarisedSample | None = field(
        default_factory=MicrofacetPolarisedSample)
    reference: NDArray[np.float64] | None = None
    base: GoniometerScene = field(default_factory=GoniometerScene)

    def __post_init__(self) -> None:
        if (self.sample is None) == (self.reference is None):
            raise ValueError("[simulation.scene] a polarimetric scene holds either a pBRDF "
                             "sample or a transmissive reference")

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> PolarimetricScene:
        cfg = dict(config)
        cfg.pop("kind", None)
        kind = str(cfg.pop("sample", "pbrdf"))
        tables: dict[str, Any] = {key: cfg.pop(key) for key in
                                  ("pbrdf", "air", "polariser", "retarder") if key in cfg}
        extra = set(tables) - {kind}
        if extra:
            raise ValueError(f"[simulation.scene] sample = {kind!r} but tables "
                             f"{sorted(extra)} are given: give the table of the sample only")
        allowed = {"sample_radius_mm", "spot_samples", "aperture_samples"}
        unknown = set(cfg) - allowed
        if unknown:
            raise ValueError(f"[simulation.scene] unknown keys of a polarimetric scene "
                             f"{sorted(unknown)}; known: sample, {', '.join(sorted(allowed))} "
                             "and the sample's table (ambient light and the signature are "
                             "not modelled with polarisation)")
        base = GoniometerScene(**cfg)
        table = tables.get(kind, {})
        if not isinstance(table, Mapping):
            raise ValueError(f"[simulation.scene.{kind}] must be a table")
        if kind == "pbrdf":
            return cls(sample=MicrofacetPolarisedSample.from_config(table), base=base)
        return cls(sample=None, reference=reference_mueller(kind, table), base=base)

    # the goniometer scene under this snapshot's optics --------------------------------
    def _scene(self, state: WorldState) -> GoniometerScene:
        g, a = _generator_analyser(state)
        if self.sample is None:
            assert self.reference is not None
            return replace(self.base, target="none",
                           direct_transmission=float(a @ self.reference @ g))
        return replace(self.base, brdf=_effective_brdf(self.sample, state), target="sample",
                       direct_transmission=float(a @ g))

    @property
    def depth_extent_mm(self) -> float:
        return self.base.depth_extent_mm

    def lit_outlines(self, state: WorldState) -> tuple[NDArray[np.float64], ...] | None:
        return self._scene(state).lit_outlines(state)

    def radiance(self, origin_mm: NDArray[np.float64], directions: NDArray[np.float64],
                 state: WorldState) -> NDArray[np.float64]:
        return self._scene(state).radiance(origin_mm, directions, state)

    def radiance_projected(self, origin_mm: NDArray[np.float64], project: Any,
                           shape: tuple[int, ...], state: WorldState) -> NDArray[np.float64]:
        return self._scene(state).radiance_projected(origin_mm, project, shape, state)

    def power_on_aperture(self, center_mm: NDArray[np.float64], facing: NDArray[np.float64],
                          diameter_mm: float, state: WorldState) -> float:
        return self._scene(state).power_on_aperture(center_mm, facing, diameter_mm, state)

    def mueller_on_aperture(self, center_mm: NDArray[np.float64],
                            facing: NDArray[np.float64], diameter_mm: float,
                            state: WorldState) -> NDArray[np.float64]:
        """The hidden truth a polarimeter on this aperture measures: the 4×4 matrix P (W
        per unit source Stokes vector and analyser row) with power = a · P · g for any
        generator g and analyser a. The reading is linear in both, so P's element (i, j)
        is the power with a = e_i and g = e_j (basis vectors, not physical states)."""
        out = np.empty((4, 4))
        basis = np.eye(4)
        for i in range(4):
            for j in range(4):
                probe = replace(state, optics=PolarisationState(generator=basis[j],
                                                                analyser=basis[i]))
                out[i, j] = self._scene(probe).power_on_aperture(center_mm, facing,
                                                                 diameter_mm, probe)
        return out

