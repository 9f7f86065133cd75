"""Stokes vectors and Mueller matrices on the virtual bench: the hidden optical train.

The emulated bench's own polarisation algebra, written apart from
:mod:`analysis.polarimetry` (which reduces what the bench measures) so that a convention
misread in one cannot hide in the other.

Conventions (stated once here; the pBRDF of :mod:`hw_mocks.sim.polarised_sample` follows
them)
-----------------------------------------------------------------------------------------
* A beam travelling along the unit vector k has the transverse basis (h, v, k),
  right-handed: v is the lab +y axis made perpendicular to k, h = v × k. For the bench's
  in-plane arms (k in the lab x–z plane) h lies in the plane of incidence ("p") and
  v = ŷ across it ("s").
* Jones vector (E_h, E_v), time dependence exp(−iωt). Stokes vector
  S = (|E_h|² + |E_v|², |E_h|² − |E_v|², 2 Re E_h E_v*, 2 Im E_h E_v*): S1 > 0 is
  horizontal, S2 > 0 is +45° (from h towards v), S3 > 0 is right-handed circular as the
  textbook Mueller matrices below take it.
* A Jones matrix J becomes the Mueller matrix M = A (J ⊗ J*) A⁻¹ (Goldstein,
  *Polarized Light*, 3rd ed., §6; Chipman, Lam & Young, *Polarized Light and Optical
  Systems*, 2018, eq. 6.99), A the matrix taking the coherency vector (E ⊗ E*) to S.
* Element angles θ are measured from h towards v. Linear polariser, transmission axis θ:
  J = R(−θ) diag(1, √ε) R(θ), ε the extinction ratio. Linear retarder, fast axis θ,
  retardance δ: J = R(−θ) diag(1, e^{iδ}) R(θ), whose Mueller matrix is Goldstein's
  eq. (6.41)/(6.54) form::

      [1, 0,              0,              0      ]
      [0, c² + s² cos δ,  cs (1 − cos δ), −s sin δ]
      [0, cs (1 − cos δ), s² + c² cos δ,  c sin δ ]
      [0, s sin δ,        −c sin δ,       cos δ  ]        c = cos 2θ, s = sin 2θ

  (a test checks the two agree). R(θ) = [[cos θ, sin θ], [−sin θ, cos θ]].

The hidden train
----------------
``[simulation.optics]`` holds the truth the analysis never reads: the source's Stokes
vector and, per arm, the elements in beam order with their **true** orientation at mount
zero and true retardance (the profile's ``[optics]`` gives the nominal ones; the
difference is the misalignment a calibration has to find)::

    [simulation.optics]
    source_stokes = [1.0, 1.0, 0.0, 0.0]   # the laser's own polarisation (S0 = 1)
    [[simulation.optics.source]]
    kind = "polariser"      # "polariser" | "retarder"
    mount = "psg_polariser" # the role whose stage turns it
    orientation_deg = 0.3   # true axis at mount 0 (nominal 0: a 0.3° offset)
    extinction = 1e-5       # polariser: power extinction ratio (default 0, ideal)
    [[simulation.optics.source]]
    kind = "retarder"
    mount = "psg_retarder"
    orientation_deg = 2.0
    retardance_deg = 94.5   # or a list with retardance_nm

The element's axis stands at orientation + mount position (the stage's physical angle).

A photoelastic modulator in the source arm (``kind = "pem"``, at most one) is a retarder
whose retardance oscillates, δ(t) = A sin ωt, with its axis at ``orientation_deg`` (a PEM
head does not turn; ``mount`` may be left out). A is read from its controller's emulator
(``modulator``, a ``simpem://`` URL) each snapshot: A = 2π · drive · ``nm_per_drive`` / λ,
``nm_per_drive`` being the head's true calibration (the driver is told a nominal one)::

    [[simulation.optics.source]]
    kind = "pem"
    orientation_deg = 45.0
    modulator = "simpem://pem"
    nm_per_drive = 1230.0

Every element of a retarder's Mueller matrix is affine in (cos δ, sin δ), so
M(δ) = M₀ + M_c cos δ + M_s sin δ (from M(0), M(π) and M(π/2)); with the Jacobi–Anger
expansions (Abramowitz & Stegun 9.1.42–43) the light leaving the generator is, per unit
source power, a steady part (M₀ + J₀(A) M_c) g and the RMS amplitudes √2 J₁(A) M_s g of its
sin ωt term and √2 J₂(A) M_c g of its cos 2ωt term (:attr:`PolarisationState.harmonics`):
what a detector's lock-in reads at 1f and 2f.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["HiddenElement", "HiddenTrain", "PolarisationState", "analysed_intensity",
           "jones_to_mueller",
           "polariser_jones", "polariser_mueller", "retarder_jones", "retarder_mueller",
           "transverse_basis"]

_Y = np.array([0.0, 1.0, 0.0])

#: A: coherency vector (E_h E_h*, E_h E_v*, E_v E_h*, E_v E_v*) → Stokes vector.
_A = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, -1j, 1j, 0]], dtype=complex)
_A_INV = np.linalg.inv(_A)


def jones_to_mueller(j: NDArray[Any]) -> NDArray[np.float64]:
    """Mueller matrices (..., 4, 4) of Jones matrices (..., 2, 2): M = A (J ⊗ J*) A⁻¹."""
    j = np.asarray(j, dtype=complex)
    jc = np.conj(j)
    # J ⊗ J* with the coherency ordering (hh, hv, vh, vv): (J⊗J*)[2a+b, 2c+d] = J_ac J*_bd
    k = np.einsum("...ac,...bd->...abcd", j, jc).reshape(*j.shape[:-2], 4, 4)
    return np.real(_A @ k @ _A_INV)


def analysed_intensity(j: NDArray[Any], analyser: NDArray[np.float64],
                       generator: NDArray[np.float64]) -> NDArray[np.float64]:
    """a · M(J) · g for Jones matrices J (..., 2, 2) without forming M: with
    M = A (J ⊗ J*) A⁻¹, a·M·g = Σ_ab U_ab (J V J†)_ab where U = (Aᵀa) and V = (A⁻¹g) are
    read as 2×2 (coherency) matrices. Twenty times cheaper than the 4×4 per ray."""
    u = (_A.T @ np.asarray(analyser, dtype=float)).reshape(2, 2)
    v = (_A_INV @ np.asarray(generator, dtype=float)).reshape(2, 2)
    j = np.asarray(j, dtype=complex)
    # written out over the 2×2 indices: numpy's stacked matmul of 2×2 matrices is slow
    cols = (j[..., 0], j[..., 1])  # column c of J: J_{·c}
    rows = [(j[..., a, 0], j[..., a, 1]) for a in (0, 1)]
    t = [[cols[0][..., a] * v[0, d] + cols[1][..., a] * v[1, d] for d in (0, 1)]
         for a in (0, 1)]  # T = J V
    total = np.zeros(j.shape[:-2], dtype=complex)
    for a in (0, 1):
        for b in (0, 1):
            if u[a, b] != 0:
                total += u[a, b] * (t[a][0] * np.conj(rows[b][0])
                                    + t[a][1] * np.conj(rows[b][1]))
    return np.real(total)


def _rot(theta: float) -> NDArray[np.float64]:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, s], [-s, c]])


def polariser_jones(theta_rad: float, extinction: float = 0.0) -> NDArray[np.complex128]:
    """Linear polariser with its transmission axis at θ (power extinction ratio ε)."""
    d = np.diag([1.0, math.sqrt(extinction)]).astype(complex)
    return np.asarray(_rot(-theta_rad) @ d @ _rot(theta_rad), dtype=np.complex128)


def retarder_jones(theta_rad: float, delta_rad: float) -> NDArray[np.complex128]:
    """Linear retarder, fast axis at θ, retardance δ (the slow axis lags by δ)."""
    d = np.diag([1.0, np.exp(1j * delta_rad)])
    return np.asarray(_rot(-theta_rad) @ d @ _rot(theta_rad), dtype=np.complex128)


def polariser_mueller(theta_rad: float, extinction: float = 0.0) -> NDArray[np.float64]:
    return jones_to_mueller(polariser_jones(theta_rad, extinction))


def retarder_mueller(theta_rad: float, delta_rad: float) -> NDArray[np.float64]:
    return jones_to_mueller(retarder_jones(theta_rad, delta_rad))


def transverse_basis(k: NDArray[np.float64], up: NDArray[np.float64] = _Y
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(h, v) of beams along unit vectors ``k`` (..., 3): v = ``up`` made perpendicular to
    k and normalised, h = v × k (the conventions above). ``up`` is the lab +y axis in the
    frame ``k`` is given in."""
    k = np.asarray(k, dtype=float)
    v = up - (k @ up)[..., None] * k
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return np.cross(v, k), v


@dataclass(frozen=True)
class HiddenElement:
    """One element of the hidden train: its true orientation at mount zero, retardance
    (degrees, one value or a table over ``retardance_nm``) and polariser extinction."""

    kind: str
    mount: str | None
    orientation_deg: float = 0.0
    retardance_deg: tuple[float, ...] = ()
    retardance_nm: tuple[float, ...] = ()
    extinction: float = 0.0
    modulator: str | None = None   # a PEM's controller (simpem:// URL)
    nm_per_drive: float = 0.0      # a PEM head's true calibration

    def mueller(self, mount_deg: float, wavelength_nm: float) -> NDArray[np.float64]:
        theta = math.radians(self.orientation_deg + mount_deg)
        if self.kind == "polariser":
            return polariser_mueller(theta, self.extinction)
        if len(self.retardance_deg) == 1:
            delta = self.retardance_deg[0]
        else:
            delta = float(np.interp(wavelength_nm, self.retardance_nm, self.retardance_deg))
        return retarder_mueller(theta, math.radians(delta))


_KEYS = {"kind", "mount", "orientation_deg", "retardance_deg", "retardance_nm", "extinction",
         "modulator", "nm_per_drive"}
_KINDS = ("polariser", "retarder", "pem")


def _hidden_element(cfg: Any, where: str) -> HiddenElement:
    if not isinstance(cfg, Mapping):
        raise ValueError(f"[simulation.optics] {where} must be a table")
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ValueError(f"[simulation.optics] {where}: unknown keys {sorted(unknown)}; "
                         f"known {sorted(_KEYS)}")
    kind = cfg.get("kind")
    if kind not in _KINDS:
        raise ValueError(f"[simulation.optics] {where}.kind must be one of {list(_KINDS)}, "
                         f"got {kind!r}")
    if kind == "pem":
        return _hidden_pem(cfg, where)
    mount = cfg.get("mount")
    if mount is not None and not isinstance(mount, str):
        raise ValueError(f"[simulation.optics] {where}.mount must be a role name")
    orientation = float(cfg.get("orientation_deg", 0.0))
    extinction = float(cfg.get("extinction", 0.0))
    if not (math.isfinite(orientation) and 0.0 <= extinction < 1.0):
        raise ValueError(f"[simulation.optics] {where}: orientation_deg must be finite and "
                         "extinction in [0, 1)")
    retardance: tuple[float, ...] = ()
    wavelengths: tuple[float, ...] = ()
    if kind == "retarder":
        raw = cfg.get("retardance_deg")
        if raw is None:
            raise ValueError(f"[simulation.optics] {where}.retardance_deg is required for a "
                             "retarder")
        retardance = tuple(float(x) for x in (raw if isinstance(raw, list) else [raw]))
        if isinstance(raw, list):
            wavelengths = tuple(float(x) for x in cfg.get("retardance_nm", []))
            if len(wavelengths) != len(retardance) or any(
                    b <= a for a, b in itertools.pairwise(wavelengths)):
                raise ValueError(f"[simulation.optics] {where}.retardance_nm must list one "
                                 "increasing wavelength per retardance value")
    return HiddenElement(kind, mount, orientation, retardance, wavelengths, extinction)


def _hidden_pem(cfg: Mapping[str, Any], where: str) -> HiddenElement:
    modulator = cfg.get("modulator")
    if not isinstance(modulator, str) or not modulator.startswith("simpem://"):
        raise ValueError(f"[simulation.optics] {where}.modulator must be the PEM "
                         f"controller's simpem:// URL, got {modulator!r}")
    nm_per_drive = float(cfg.get("nm_per_drive", 0.0))
    orientation = float(cfg.get("orientation_deg", 0.0))
    if not (math.isfinite(nm_per_drive) and nm_per_drive > 0 and math.isfinite(orientation)):
        raise ValueError(f"[simulation.optics] {where}: a pem needs nm_per_drive > 0 (nm "
                         "of peak retardation at drive 1) and a finite orientation_deg")
    mount = cfg.get("mount")
    if mount is not None and not isinstance(mount, str):
        raise ValueError(f"[simulation.optics] {where}.mount must be a role name")
    return HiddenElement("pem", mount, orientation, modulator=modulator,
                         nm_per_drive=nm_per_drive)


def _pem_channels(e: HiddenElement, theta_deg: float, amplitude_rad: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The PEM's steady, 1f and 2f Mueller parts (module docstring)."""
    theta = math.radians(theta_deg)
    m_plus, m_minus = retarder_mueller(theta, 0.0), retarder_mueller(theta, math.pi)
    m0, mc = 0.5 * (m_plus + m_minus), 0.5 * (m_plus - m_minus)
    ms = retarder_mueller(theta, math.pi / 2) - m0
    # imported here: scipy.special costs about 1 s of CPU to import, and every emulated
    # bench (a server, a test process) loads this module whether or not it has a PEM
    from scipy import special

    j0, j1, j2 = (float(special.jv(n, amplitude_rad)) for n in (0, 1, 2))
    return m0 + j0 * mc, math.sqrt(2.0) * j1 * ms, math.sqrt(2.0) * j2 * mc


@dataclass(frozen=True)
class PolarisationState:
    """The train as it stands now, for one snapshot of the world.

    ``generator``: the Stokes vector leaving the PSG per unit source power, in the basis
    of the beam towards the sample. ``analyser``: the first row of the PSA's Mueller
    matrix (what the detector's intensity is of a Stokes vector arriving on it), in the
    basis of the light travelling towards the detector.
    """

    generator: NDArray[np.float64]
    analyser: NDArray[np.float64]
    #: A PEM generator's modulated parts: (harmonic n, Stokes vector of its RMS amplitude)
    #: for n = 1 (the sin ωt term) and 2 (the cos 2ωt term); ``generator`` is the mean.
    harmonics: tuple[tuple[int, NDArray[np.float64]], ...] = ()
    #: The modulation frequency ω/2π in Hz (None without a PEM).
    modulation_hz: float | None = None


@dataclass(frozen=True)
class HiddenTrain:
    """``[simulation.optics]``: the source's polarisation and the true elements."""

    source_stokes: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    source: tuple[HiddenElement, ...] = ()
    detector: tuple[HiddenElement, ...] = ()

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> HiddenTrain:
        if not isinstance(cfg, Mapping):
            raise ValueError("[simulation.optics] must be a table")
        unknown = set(cfg) - {"source_stokes", "source", "detector"}
        if unknown:
            raise ValueError(f"[simulation.optics]: unknown keys {sorted(unknown)}; known "
                             "source_stokes, source, detector")
        stokes = tuple(float(x) for x in cfg.get("source_stokes", (1.0, 0.0, 0.0, 0.0)))
        if (len(stokes) != 4 or stokes[0] <= 0.0
                or math.hypot(stokes[1], stokes[2], stokes[3]) > stokes[0] * (1 + 1e-12)):
            raise ValueError("[simulation.optics] source_stokes must be 4 numbers with "
                             "S0 > 0 and S1² + S2² + S3² ≤ S0²")
        s0 = stokes[0]
        arms = {}
        for arm in ("source", "detector"):
            raw = cfg.get(arm, [])
            if not isinstance(raw, Sequence) or isinstance(raw, str):
                raise ValueError(f"[simulation.optics] {arm} must be an array of tables")
            arms[arm] = tuple(_hidden_element(e, f"{arm}[{i}]") for i, e in enumerate(raw))
        pems = [e for e in (*arms["source"], *arms["detector"]) if e.kind == "pem"]
        if pems and (len(pems) > 1 or any(e.kind == "pem" for e in arms["detector"])):
            raise ValueError("[simulation.optics]: one pem at most, in the source arm")
        normalised = (1.0, stokes[1] / s0, stokes[2] / s0, stokes[3] / s0)
        return cls(normalised, arms["source"], arms["detector"])

    @property
    def mounts(self) -> tuple[str, ...]:
        return tuple(e.mount for e in (*self.source, *self.detector) if e.mount is not None)

    @property
    def modulators(self) -> tuple[str, ...]:
        """The PEM controllers' URLs (their drive is part of the world's state)."""
        return tuple(e.modulator for e in self.source if e.modulator is not None)

    def state(self, position: Callable[[str], float], wavelength_nm: float,
              modulator: Callable[[str], tuple[float, float]] | None = None
              ) -> PolarisationState:
        """The generator and analyser now, with each mount's angle from ``position`` and a
        PEM controller's (drive 0..1, frequency Hz) from ``modulator``."""
        g = np.array(self.source_stokes)
        parts: list[tuple[int, NDArray[np.float64]]] = []
        frequency = None
        for e in self.source:
            mount = position(e.mount) if e.mount else 0.0
            if e.kind == "pem":
                if modulator is None or e.modulator is None:
                    raise ValueError("a pem in [simulation.optics] needs its controller read")
                drive, frequency = modulator(e.modulator)
                amplitude = 2.0 * math.pi * drive * e.nm_per_drive / wavelength_nm
                steady, first, second = _pem_channels(e, e.orientation_deg + mount, amplitude)
                parts = [(1, first @ g), (2, second @ g)]
                g = steady @ g
                continue
            m_e = e.mueller(mount, wavelength_nm)
            g = m_e @ g
            parts = [(n, m_e @ v) for n, v in parts]
        m = np.eye(4)
        for e in self.detector:
            m = e.mueller(position(e.mount) if e.mount else 0.0, wavelength_nm) @ m
        return PolarisationState(generator=g, analyser=m[0].copy(), harmonics=tuple(parts),
                                 modulation_hz=frequency)
