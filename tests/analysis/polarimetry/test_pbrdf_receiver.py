"""The pBRDF as a finite receiver reads it (:func:`analysis.polarimetry.pbrdf.pbrdf_on_receiver`,
:mod:`analysis.polarimetry.receiver_nodes`): constants average to themselves, the second-order
term of a curved model is the analytic one, and the fit refines its quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.brdf.reduction.detector import solid_angle_sr
from analysis.brdf.reduction.receiver import ReceiverGeometry, receiver_factor
from analysis.polarimetry.elements import rotation
from analysis.polarimetry.pbrdf import (
    QUADRATURE_TOLERANCE,
    fit_pbrdf,
    pbrdf,
    pbrdf_on_receiver,
)
from analysis.polarimetry.receiver_nodes import mueller_nodes
from analysis.polarimetry.validation import PolarimetryInputError

APERTURE_MM, DISTANCE_MM = 5.0, 300.0
OMEGA = solid_angle_sr(APERTURE_MM, DISTANCE_MM)[0]
GLASS = [1.5, 0.0, 0.15, 0.3, 0.0]
TI, TR = math.radians(50.0), math.radians(30.0)


def _receiver(beam_mm: float = 1.0) -> ReceiverGeometry:
    return ReceiverGeometry(beam_mm, DISTANCE_MM, APERTURE_MM, OMEGA)


def test_a_constant_matrix_averages_to_itself():
    rng = np.random.default_rng(7)
    const = rng.normal(size=(4, 4))
    nodes = mueller_nodes([0.3, 0.9], 0.0, [0.5, 1.2], math.pi, _receiver(), level=2,
                          normalise=True)
    values = np.broadcast_to(const, (nodes.weights.size, 4, 4))
    np.testing.assert_allclose(nodes.average(values), [const, const], rtol=0, atol=1e-13)


def test_a_depolariser_reads_the_receiver_factor_times_itself():
    """n → 1 leaves only the Lambertian layer (ρ/π)·diag(1, 0, 0, 0), constant in angle
    and in frame: the normalised reading is it exactly, the unnormalised one G times it
    with G the scalar instrument function's receiver factor."""
    p = [1.0 + 1e-6, 0.0, 0.15, 0.3, 0.0]
    ti, tr = np.radians([20.0, 50.0]), np.radians([60.0, 30.0])
    point = pbrdf(p, ti, 0.0, tr, math.pi)
    avg = pbrdf_on_receiver(p, ti, 0.0, tr, math.pi, _receiver(), level=2, normalise=True)
    np.testing.assert_allclose(avg, point, rtol=1e-9, atol=1e-15)
    g = receiver_factor(ti, 0.0, tr, math.pi, receiver=_receiver())
    raw = pbrdf_on_receiver(p, ti, 0.0, tr, math.pi, _receiver(), level=2)
    np.testing.assert_allclose(raw[:, 0, 0], g * point[:, 0, 0], rtol=1e-6)


def _receiver_frame_matrix(p: float, q: float, turn: bool = True) -> np.ndarray:
    """The point model at the direction of tangent-plane offset (p, q) from the central ray
    (p in its plane of incidence towards larger θr, q across), turned from that
    direction's own global frame into the receiver's (the central s axis made ⟂ the
    direction), written out from the frames' vectors."""
    w0 = np.array([-math.sin(TR), 0.0, math.cos(TR)])        # φr = π
    b1 = np.array([-math.cos(TR), 0.0, -math.sin(TR)])       # ∂ω/∂θr
    b2 = np.array([0.0, -1.0, 0.0])
    u = w0 + p * b1 + q * b2
    u /= np.linalg.norm(u)
    theta, phi = math.acos(u[2]), math.atan2(u[1], u[0])
    m = pbrdf(GLASS, TI, 0.0, theta, phi)[0]
    s_own = np.array([-math.sin(phi), math.cos(phi), 0.0])
    s_c = np.array([-math.sin(math.pi), math.cos(math.pi), 0.0])
    s_rx = s_c - (s_c @ u) * u
    s_rx /= np.linalg.norm(s_rx)
    e1_own, e2_own = np.cross(u, s_own), -s_own
    e1_rx = np.cross(u, s_rx)
    # Stokes components in a frame turned by ψ (from e₁ towards e₂): R(ψ) of elements
    psi = math.atan2(e1_rx @ e2_own, e1_rx @ e1_own)
    return rotation(psi) @ m if turn else m


def test_the_second_order_term_of_a_curved_model_is_the_analytic_one():
    """A point spot and a disk of radius a at d: in the tangent-plane offsets (p, q) of
    the node directions the weights are ∝ cos θ(u)·(1 + p² + q²)⁻², the disk's moments
    ⟨p²⟩ = ⟨q²⟩ = s² = a²/(4d²), so the normalised reading is

        F₀ + s² (−tan θr ∂_p F + ½(∂²_p F + ∂²_q F)) + O(s⁴),

    F in the receiver's frames. The glass's lobe at θr 30° curves by ~1/(2α²) ≈ 22 per
    rad²: the term is ~4·10⁻⁴ of F, s⁴ terms ~10⁻⁶ of it."""
    s2 = (0.5 * APERTURE_MM / DISTANCE_MM) ** 2 / 4.0
    h = 2e-3

    def second_order(turn: bool) -> tuple[np.ndarray, np.ndarray]:
        f = {(i, j): _receiver_frame_matrix(i * h, j * h, turn)
             for i in (-1, 0, 1) for j in (-1, 0, 1)}
        f0 = f[0, 0]
        d_p = (f[1, 0] - f[-1, 0]) / (2 * h)
        d_pp = (f[1, 0] - 2 * f0 + f[-1, 0]) / h**2
        d_qq = (f[0, 1] - 2 * f0 + f[0, -1]) / h**2
        return f0, s2 * (-math.tan(TR) * d_p + 0.5 * (d_pp + d_qq))

    f0, term = second_order(turn=True)
    avg = pbrdf_on_receiver(GLASS, TI, 0.0, TR, math.pi, _receiver(1e-6), level=3,
                            normalise=True)[0]
    scale = float(np.max(np.abs(term)))
    assert scale > 3e-5 * f0[0, 0]  # the term is there to be checked (6e-5 of m00)
    # steps h = 2e-3 and 1e-3 agree to 1e-3 of the term; the s⁴ terms are ~1e-4 of it
    np.testing.assert_allclose(avg - f0, term, rtol=0, atol=0.01 * scale)
    # the frames matter: in each direction's own frame the q curvature of m11, m22 is
    # another (the 2ψ² mixing, ψ ≈ q cot θr), by more than the tolerance tenfold
    _, unturned = second_order(turn=False)
    assert np.max(np.abs(unturned - term)) > 0.1 * scale


def test_a_level_outside_the_ladder_is_refused():
    with pytest.raises(PolarimetryInputError, match="level"):
        pbrdf_on_receiver(GLASS, TI, 0.0, TR, math.pi, _receiver(), level=9)


def test_the_fit_recovers_the_glass_from_the_receivers_readings():
    """Readings made by the finite receiver (level 3) with σ of 10⁻⁵ of m00 on every
    element: the point model is refused by far, the receiver's model passes the gate at
    the truth, and its quadrature's error bound is inside the tolerance."""
    ti = np.radians([50.0, 50.0, 50.0])
    tr = np.radians([30.0, 50.0, 70.0])
    truth = pbrdf_on_receiver(GLASS, ti, 0.0, tr, math.pi, _receiver(), level=3)
    sigma = 1e-5 * truth[:, 0, 0]
    cov = np.array([np.eye(16) * s**2 for s in sigma])
    rng = np.random.default_rng(11)
    data = truth + rng.normal(size=truth.shape) * sigma[:, None, None]
    start = [1.45, 0.0, 0.2, 0.2, 0.0]
    point = fit_pbrdf(data, cov, ti, 0.0, tr, math.pi, start=start, fixed=("k",))
    assert point.goodness.p_value < 1e-6
    fit = fit_pbrdf(data, cov, ti, 0.0, tr, math.pi, start=start, fixed=("k",),
                    receiver=_receiver())
    assert fit.goodness.p_value > 1e-3, fit.goodness.verdict()
    assert fit.quadrature_error <= QUADRATURE_TOLERANCE and fit.receiver_level is not None
    free = fit.sigma > 0
    pulls = (fit.params[free] - np.array(GLASS)[free]) / fit.sigma[free]
    assert np.all(np.abs(pulls) < 4.0), pulls
