"""Seeded synthetic goniometer scans for the fitting tests (not a test module)."""

import numpy as np

from analysis.brdf.model import BRDFModel

INCIDENCE_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 70.0)


def scan_angles(n_r: int = 35, *, out_of_plane: bool = True):
    """(θi, φi, θr, φr) of an in-plane scan (both sides of the normal) at each θi, plus a
    sparse out-of-plane ring; flat arrays in radians."""
    tr = np.radians(np.linspace(0.0, 85.0, n_r))
    rows = []
    for t in np.radians(INCIDENCE_DEG):
        for pr in (np.pi, 0.0):
            rows.append(
                np.stack([np.full_like(tr, t), np.zeros_like(tr), tr, np.full_like(tr, pr)])
            )
        if out_of_plane:
            ring = np.radians(np.arange(20.0, 181.0, 40.0))
            rows.append(
                np.stack([np.full_like(ring, t), np.zeros_like(ring), np.full_like(ring, t), ring])
            )
    a = np.concatenate(rows, axis=1)
    return a[0], a[1], a[2], a[3]


def noisy(model: BRDFModel, params, angles, *, seed: int, rel: float = 0.03, floor: float = 0.0):
    """Model values with Gaussian noise of std rel·f + floor·max(f); returns (y, sigma, f)."""
    f = model.evaluate(params, *angles)
    sig = rel * f + floor * float(np.max(f))
    sig = np.maximum(sig, 1e-12)
    rng = np.random.default_rng(seed)
    return f + sig * rng.standard_normal(f.shape), sig, f
