"""Cost of the localiser's point-response model on the wall's rays (``ray_model``).

``analysis.lightfield.ray_fit.ray_model`` evaluates the filtered delta of each point on
every wall row (and its derivative in θ*) through an inverse FFT over the N angle orders.
The phase factors were computed for all N orders although the filter passes only
2 p̂ + 1 of them; the model now evaluates only the passed orders.  This script times the
model against :func:`reference_ray_model` (every order, as before) on the localiser's
typical call — the 24 nodes of one segment of the extended-object test (the largest
call) — at N = 128 and 1024, and checks the two give identical arrays.  The times are
CPU seconds per call, the median of ``--repeat``, the two forms alternated so that the
machine's load falls on both alike.

    python benchmarks/bench_ray_model.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.append(str(Path(__file__).resolve().parents[1]))

import numpy as np

from analysis.lightfield import LightField2D, theta_grid
from analysis.lightfield.ray_fit import ray_model
from analysis.lightfield.spectral import fourier_orders, synthesize

DOMAIN = (-0.6, 0.6)
#: (N, p̂): the validation matrix's 128 angles with the 0.1° wall's p̂, and 1024 angles
CASES = ((128, 45), (1024, 60))


def reference_ray_model(lf_wall, use, phi, pos):
    """The model evaluated on every order (the form before the change): the reference the
    fast form must equal."""
    th = lf_wall.theta_rad
    a, b = lf_wall.domain_rad
    omega = 2 * np.pi / (b - a)
    p = fourier_orders(th.size)
    c = np.asarray(lf_wall.y_mm, dtype=float)
    yk, zk = pos[:, 0][:, None], pos[:, 1][:, None]
    u = (c[None, :] - yk) / (-zk)
    coef = phi * np.exp(-1j * p * omega * (np.arctan(u)[..., None] - 0.5 * (a + b)))
    resp = synthesize(coef, axis=-1).real[..., use] / (b - a)
    d_t = synthesize(coef * (-1j * p * omega), axis=-1).real[..., use] / (b - a)
    w = 1.0 / (1.0 + u**2)
    return resp, d_t * (w / zk)[..., None], d_t * (w * (c[None, :] - yk) / zk**2)[..., None]


def case(n: int, p_hat: int, k: int = 24):
    """A wall of 201 points, a filter passing |p| ≤ p̂ (a Wiener-like taper), and k points
    across a 4 mm segment at −200 mm."""
    th = theta_grid(DOMAIN, n)
    c = np.arange(-100.0, 100.1, 1.0)
    lf = LightField2D(np.zeros((c.size, n)), c, th, DOMAIN)
    p = np.abs(fourier_orders(n))
    phi = np.where(p <= p_hat, 1.0 / (1.0 + (p / p_hat) ** 8), 0.0)
    use = (th >= -0.5) & (th <= 0.5)
    pos = np.column_stack([np.linspace(-2.0, 2.0, k), np.full(k, -200.0)])
    return lf, use, phi, pos


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    print("| N | p̂ | every order (s) | passed orders (s) | speed-up | identical |")
    print("|---|---|---|---|---|---|")
    for n, p_hat in CASES:
        args_ = case(n, p_hat)
        times: dict[str, list[float]] = {"ref": [], "new": []}
        for _ in range(args.repeat):
            for name, f in (("ref", reference_ray_model), ("new", ray_model)):
                t0 = time.process_time()
                f(*args_)
                times[name].append(time.process_time() - t0)
        same = all(np.array_equal(x, y) for x, y in zip(reference_ray_model(*args_),
                                                         ray_model(*args_), strict=True))
        ref, new = statistics.median(times["ref"]), statistics.median(times["new"])
        print(f"| {n} | {p_hat} | {ref:.3f} | {new:.3f} | {ref / new:.2f}× | {same} |",
              flush=True)


if __name__ == "__main__":
    main()
