"""Goniometer kinematics: axis positions ↔ scattering angles (θi, φi, θr, φr).

Geometry of an in-plane or out-of-plane point-detector goniometer (ADR 0012): a fixed source, a
sample that rotates, a detector on an arm that orbits in the horizontal plane.

Frames and signs (all angles in **degrees**)
--------------------------------------------
Lab frame (right-handed): +Z points **up** along the vertical rotation axis of the sample
stage and of the detector arm; X, Y span the horizontal scattering plane. Lab azimuths in
that plane are measured from +X, counter-clockwise when seen from above (right-handed
about +Z). The source direction (from the sample centre towards the source) has lab
azimuth ``source_theta_deg`` from the profile's geometry.

Axis readings (positive = counter-clockwise seen from above for rotary stages about Z):

``sample_theta``
    Rotation of the sample about +Z. At 0 the sample normal points at the source.
``detector_theta``
    Arm angle measured from the source direction: the detector direction has lab
    azimuth ``source_theta_deg + detector_theta``. Its magnitude is the bistatic angle
    2β (0 = detector in the incident beam, ±180 = straight through).
``sample_tilt`` (out-of-plane benches)
    Rotation about the sample's x axis (horizontal, in the sample surface): a positive
    tilt raises the normal above the horizontal plane.
``sample_phi`` (out-of-plane benches)
    Rotation of the sample about its own normal (azimuth stage), right-handed about
    the normal.

The composed sample→lab rotation is ``M = Rz(s + θs) · M0 · Rx(τ) · Rz(ϕ)`` with
``M0 = [x_s ↦ −Y, y_s ↦ −Z, z_s ↦ +X]``: at zero tilt and azimuth the sample normal z_s
lies in the horizontal plane, the sample x axis x_s is horizontal (on the source side of
the normal when sample_theta > 0) and y_s points down, so (x_s, y_s, z_s) is right-handed.

Sample frame: the normal is +z, azimuth φ is measured from x_s towards y_s, and both
direction vectors point **away** from the surface (ωi towards the source, ωr towards the
detector), ω = (sinθ cosφ, sinθ sinφ, cosθ). This is the convention of
:mod:`analysis.brdf.geometry` (there in radians): the specular direction is θr = θi,
φr = φi + 180°. In-plane points have φ ∈ {0°, 180°}; for sample_theta > 0 the source is
at φi = 0 and the specular detector at detector_theta = 2·sample_theta. When θ = 0 the
azimuth is undefined and reported as 0.

Type (i) goniometer (:class:`TypeIKinematics`, ADR 0099)
----------------------------------------------------------
The sample lies still, normal up: the sample frame *is* the lab frame (x_s = +X,
y_s = +Y, z_s = +Z). The source and the detector each ride an arc rail whose plane turns
about +Z on an azimuth stage:

``source_arc`` / ``detector_arc``
    Signed angle of the head along its arc from the pole (+Z), less the profile's
    ``arc_offset_deg``: a reading a at azimuth reading ϕ points the head along
    (sin a cos ϕ, sin a sin ϕ, cos a), so a negative arc reaches the far side of the rail.
``source_azimuth`` / ``detector_azimuth``
    Azimuth of the arc's plane from +X, counter-clockwise seen from above, less
    ``azimuth_offset_deg``.

So θi = |source_arc|, φi = source_azimuth (+180° for a negative arc), and the same for
the detector: the same (θi, φi, θr, φr) are the same two directions in the sample frame on
both types, which is all the BRDF sees.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:
    from instrument.bench.profile import GeometrySpec

__all__ = [
    "IN_PLANE_AXES",
    "OUT_OF_PLANE_AXES",
    "TYPE_I_AXES",
    "Angles",
    "InPlaneKinematics",
    "Kinematics",
    "OutOfPlaneKinematics",
    "TypeIKinematics",
    "UnreachableError",
    "direction",
    "kinematics_for",
    "kinematics_of",
    "wrap180",
]

IN_PLANE_AXES = ("sample_theta", "detector_theta")
OUT_OF_PLANE_AXES = ("sample_theta", "sample_tilt", "sample_phi", "detector_theta")
TYPE_I_AXES = ("source_arc", "source_azimuth", "detector_arc", "detector_azimuth")

_EPS = 1e-9


class UnreachableError(ValueError):
    """The geometry cannot produce the requested angles (not a limit problem)."""


def wrap180(angle_deg: float) -> float:
    """Wrap an angle into (−180, 180] degrees."""
    a = math.fmod(angle_deg, 360.0)
    if a <= -180.0:
        a += 360.0
    elif a > 180.0:
        a -= 360.0
    return a


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    """Unit vector (sinθ cosφ, sinθ sinφ, cosθ) in the sample frame, shape (3,)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _polar(vec: np.ndarray) -> tuple[float, float]:
    """(θ, φ) in degrees of a sample-frame vector; φ in [0, 360), 0 where θ = 0."""
    v = vec / np.linalg.norm(vec)
    # atan2 keeps full precision near the pole, where acos(z) loses half the digits.
    theta = math.degrees(math.atan2(math.hypot(float(v[0]), float(v[1])), float(v[2])))
    if math.hypot(v[0], v[1]) < 1e-15:
        return theta, 0.0
    phi = math.degrees(math.atan2(float(v[1]), float(v[0]))) % 360.0
    if phi > 360.0 - 1e-9:
        phi = 0.0
    return theta, phi


@dataclass(frozen=True)
class Angles:
    """Scattering angles in the sample frame, degrees (see the module docstring)."""

    theta_i: float
    phi_i: float
    theta_r: float
    phi_r: float

    @property
    def omega_i(self) -> np.ndarray:
        return direction(self.theta_i, self.phi_i)

    @property
    def omega_r(self) -> np.ndarray:
        return direction(self.theta_r, self.phi_r)

    @property
    def bistatic_deg(self) -> float:
        """Angle 2β between the source and detector directions, degrees."""
        wi, wr = self.omega_i, self.omega_r
        return math.degrees(math.atan2(float(np.linalg.norm(np.cross(wi, wr))),
                                       float(np.dot(wi, wr))))

    def reciprocal(self) -> Angles:
        """Source and detector exchanged (Helmholtz reciprocity: f is unchanged)."""
        return Angles(self.theta_r, self.phi_r, self.theta_i, self.phi_i)

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.theta_i, self.phi_i, self.theta_r, self.phi_r)


def _rz(angle_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(angle_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


#: Sample axes at zero rotation, as columns in the lab frame: x_s=−Y, y_s=−Z, z_s=+X.
_M0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _lab_horizontal(azimuth_deg: float) -> np.ndarray:
    a = math.radians(azimuth_deg)
    return np.array([math.cos(a), math.sin(a), 0.0])


class Kinematics(ABC):
    """Map axis positions (by role) to :class:`Angles` and back."""

    axes: tuple[str, ...] = ()

    def __init__(self, *, source_theta_deg: float = 0.0) -> None:
        self.source_theta_deg = float(source_theta_deg)

    @abstractmethod
    def angles(self, positions: Mapping[str, float]) -> Angles:
        """Angles seen by the sample at these axis positions (degrees)."""

    @abstractmethod
    def solutions(self, angles: Angles) -> list[dict[str, float]]:
        """Every set of axis positions that realises ``angles`` (may be empty)."""

    def positions(
        self, angles: Angles, *, limits: Mapping[str, tuple[float, float]] | None = None
    ) -> dict[str, float]:
        """The first solution inside ``limits`` (or the first solution at all).

        Raises
        ------
        UnreachableError
            No axis setting of this geometry realises the angles.
        """
        sols = self.solutions(angles)
        if not sols:
            raise UnreachableError(f"{angles} cannot be reached with a {type(self).__name__}")
        if limits:
            for sol in sols:
                if all(limits.get(r, (-math.inf, math.inf))[0] - 1e-9 <= v
                       <= limits.get(r, (-math.inf, math.inf))[1] + 1e-9
                       for r, v in sol.items()):
                    return sol
        return sols[0]

    def sample_to_lab(self, positions: Mapping[str, float]) -> np.ndarray:
        """3×3 rotation taking sample-frame vectors to the lab frame."""
        a = self.source_theta_deg + float(positions.get("sample_theta", 0.0))
        tilt = float(positions.get("sample_tilt", 0.0))
        phi = float(positions.get("sample_phi", 0.0))
        return cast(np.ndarray, _rz(a) @ _M0 @ _rx(tilt) @ _rz(phi))

    def _angles_general(self, positions: Mapping[str, float]) -> Angles:
        m = self.sample_to_lab(positions)
        s = _lab_horizontal(self.source_theta_deg)
        d = _lab_horizontal(self.source_theta_deg + float(positions["detector_theta"]))
        ti, pi = _polar(m.T @ s)
        tr, pr = _polar(m.T @ d)
        return Angles(ti, pi, tr, pr)


class InPlaneKinematics(Kinematics):
    """Fixed source, sample rotation ``sample_theta``, detector arm ``detector_theta``.

    Closed form: with the signed in-plane angle u = θ for φ = 0 and u = −θ for φ = 180°,
    sample_theta = u_i and detector_theta = u_i − u_r (the specular detector sits at
    detector_theta = 2·sample_theta).
    """

    axes = IN_PLANE_AXES

    def angles(self, positions: Mapping[str, float]) -> Angles:
        st = float(positions["sample_theta"])
        dt = float(positions["detector_theta"])
        ui, ur = wrap180(st), wrap180(st - dt)
        return Angles(abs(ui), 0.0 if ui >= 0 else 180.0, abs(ur), 0.0 if ur >= 0 else 180.0)

    def solutions(self, angles: Angles) -> list[dict[str, float]]:
        ui = self._signed(angles.theta_i, angles.phi_i)
        ur = self._signed(angles.theta_r, angles.phi_r)
        if ui is None or ur is None:
            return []
        return [{"sample_theta": ui, "detector_theta": wrap180(ui - ur)}]

    @staticmethod
    def _signed(theta: float, phi: float) -> float | None:
        p = phi % 360.0
        if min(p, 360.0 - p) < 1e-6:
            return theta
        if abs(p - 180.0) < 1e-6:
            return -theta
        if abs(theta) < _EPS:  # at the pole the azimuth does not matter
            return 0.0
        return None


class OutOfPlaneKinematics(Kinematics):
    """Adds sample tilt and azimuth: four axes for four angles.

    Inverse: the bistatic angle fixes |detector_theta| = 2β; for each sign, the unique
    rotation M with M ωi = S and M ωr = D (S, D the lab source and detector directions)
    follows from the two orthonormal triads built on the pairs, M = F Eᵀ. Its Euler
    angles: the lab normal M e_z = (cos a cos τ, sin a cos τ, sin τ) gives a and τ, then
    (Rz(a) M0 Rx(τ))ᵀ M = Rz(ϕ) gives ϕ. Needs 0 < 2β < 180° (the guard's minimum
    bistatic angle keeps it away from 0) and |τ| < 90° (gimbal lock).
    """

    axes = OUT_OF_PLANE_AXES

    def angles(self, positions: Mapping[str, float]) -> Angles:
        return self._angles_general(positions)

    def solutions(self, angles: Angles) -> list[dict[str, float]]:
        wi, wr = angles.omega_i, angles.omega_r
        two_beta = angles.bistatic_deg
        if two_beta < 1e-6 or two_beta > 180.0 - 1e-6:
            return []
        e = _triad(wi, wr)
        out = []
        for d in (two_beta, -two_beta):
            s = _lab_horizontal(self.source_theta_deg)
            dv = _lab_horizontal(self.source_theta_deg + d)
            m = _triad(s, dv) @ e.T
            n = m[:, 2]
            tilt = math.degrees(math.asin(max(-1.0, min(1.0, float(n[2])))))
            if abs(tilt) > 90.0 - 1e-6:
                continue
            a = math.degrees(math.atan2(float(n[1]), float(n[0])))
            q = (_rz(a) @ _M0 @ _rx(tilt)).T @ m
            phi = math.degrees(math.atan2(float(q[1, 0]), float(q[0, 0])))
            out.append({
                "sample_theta": wrap180(a - self.source_theta_deg),
                "sample_tilt": tilt,
                "sample_phi": wrap180(phi),
                "detector_theta": d,
            })
        return out


def _triad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Orthonormal columns (a, b⊥, a×b⊥) built on two non-parallel vectors."""
    e1 = a / np.linalg.norm(a)
    b_perp = b - np.dot(b, e1) * e1
    e2 = b_perp / np.linalg.norm(b_perp)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


class TypeIKinematics(Kinematics):
    """Source and detector arms over a stationary, horizontal sample (module docstring).

    ``offsets`` maps an axis role to its reading at the arm's zero (``arc_offset_deg``,
    ``azimuth_offset_deg`` of the profile's arms). Each arm reaches a direction two ways,
    (a, ϕ) and (−a, ϕ + 180°); :meth:`solutions` lists the four combinations, the
    positive arcs first. At the pole the azimuth is free and is kept at its zero.
    """

    axes = TYPE_I_AXES

    def __init__(self, *, offsets: Mapping[str, float] | None = None) -> None:
        super().__init__(source_theta_deg=0.0)
        self.offsets = {r: float((offsets or {}).get(r, 0.0)) for r in TYPE_I_AXES}

    def sample_to_lab(self, positions: Mapping[str, float]) -> np.ndarray:
        return np.eye(3)

    def arm_direction(self, positions: Mapping[str, float], arm: str) -> np.ndarray:
        """Unit vector from the sample centre to the ``arm`` ("source" or "detector")
        head, lab (= sample) frame."""
        a = float(positions[f"{arm}_arc"]) - self.offsets[f"{arm}_arc"]
        p = float(positions[f"{arm}_azimuth"]) - self.offsets[f"{arm}_azimuth"]
        return direction(a, p)

    def angles(self, positions: Mapping[str, float]) -> Angles:
        ti, pi = _polar(self.arm_direction(positions, "source"))
        tr, pr = _polar(self.arm_direction(positions, "detector"))
        return Angles(ti, pi, tr, pr)

    def solutions(self, angles: Angles) -> list[dict[str, float]]:
        if not (0.0 <= angles.theta_i <= 180.0 and 0.0 <= angles.theta_r <= 180.0):
            return []
        src = self._arm("source", angles.theta_i, angles.phi_i)
        det = self._arm("detector", angles.theta_r, angles.phi_r)
        return [{**s, **d} for s in src for d in det]

    def _arm(self, arm: str, theta: float, phi: float) -> list[dict[str, float]]:
        arc, az = f"{arm}_arc", f"{arm}_azimuth"
        if abs(theta) < _EPS:
            return [{arc: self.offsets[arc], az: self.offsets[az]}]
        return [{arc: theta + self.offsets[arc], az: wrap180(phi) + self.offsets[az]},
                {arc: -theta + self.offsets[arc],
                 az: wrap180(phi + 180.0) + self.offsets[az]}]


def kinematics_of(geometry: GeometrySpec) -> Kinematics:
    """The kinematics of a profile's ``[geometry]``: its goniometer type, its kind and its
    source direction (type ii) or its arms' stage offsets (type i)."""
    if geometry.is_type_i:
        offsets: dict[str, float] = {}
        for arm, spec in (("source", geometry.source_arm),
                          ("detector", geometry.detector_arm)):
            if spec is not None:
                offsets[f"{arm}_arc"] = spec.arc_offset_deg
                offsets[f"{arm}_azimuth"] = spec.azimuth_offset_deg
        return TypeIKinematics(offsets=offsets)
    return kinematics_for(geometry.kind, source_theta_deg=geometry.source_theta_deg)


def kinematics_for(kind: str, *, source_theta_deg: float = 0.0) -> Kinematics:
    """Kinematics for a profile geometry kind (``"in_plane"`` or ``"out_of_plane"``)."""
    if kind == "in_plane":
        return InPlaneKinematics(source_theta_deg=source_theta_deg)
    if kind == "out_of_plane":
        return OutOfPlaneKinematics(source_theta_deg=source_theta_deg)
    raise ValueError(f"unknown geometry kind {kind!r}")


def same_directions(a: Angles, b: Angles, *, tol: float = 1e-7) -> bool:
    """True when both incident and scattered directions agree within ``tol`` (unit vectors)."""
    return bool(np.linalg.norm(a.omega_i - b.omega_i) < tol
                and np.linalg.norm(a.omega_r - b.omega_r) < tol)


def positions_close(a: Mapping[str, float], b: Mapping[str, float], axes: Sequence[str],
                    *, tol: float = 1e-6) -> bool:
    """True when every rotary axis agrees within ``tol`` degrees, modulo 360."""
    return all(abs(wrap180(a[k] - b[k])) < tol for k in axes)
