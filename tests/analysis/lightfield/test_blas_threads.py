"""The located objects do not depend on how many threads the BLAS uses.

Behind the brushed metal the pair one blur apart came out one object with one OpenBLAS
thread and with a phantom beside it with two: the amplitudes were solved from the normal
equations (``pinv(XᵀX)``, the condition number squared) and the joint position fits
stopped by loose tolerances of iterative trust-region steps, so the rounding of the BLAS's
blocking reached the decisions (ADR 0109).  Here the same scans run under
``threadpoolctl`` limits of 1 and 2 BLAS threads must give the same objects: the same count
and flags, positions to 1 % of the blur, significances to 5 % (measured: ≤ 1.6 %).
"""

from __future__ import annotations

import numpy as np
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")


def _located(bench, wall: str, scene: str, blur: float, seed: int, threads: int):
    brdf = bench.walls()[wall]
    objects = bench.scenes(blur)[scene]
    lf = bench.render(brdf, objects, None, "")
    with threadpoolctl.threadpool_limits(limits=threads, user_api="blas"):
        return bench.locate(lf, brdf, seed)[0]


@pytest.mark.slow
@pytest.mark.timeout(1800)  # four searches; two BLAS threads on a busy box spin
@pytest.mark.parametrize(("wall", "scene", "blur", "seed"), [
    ("brushed_metal", "pair_1blur", 6.5, 1),  # the wall's blur at −200 mm
    ("coated_paper_glossy", "ratio_100", 11.4, 6),
])
def test_the_objects_are_the_same_with_one_and_two_blas_threads(bench, wall, scene, blur,
                                                                 seed):
    one = _located(bench, wall, scene, blur, seed, 1)
    two = _located(bench, wall, scene, blur, seed, 2)
    assert one.count == two.count and one.count >= 1
    assert one.quality == two.quality
    for k in range(one.count):
        tol = 0.01 * one.resolutions[k].transverse_mm
        assert np.allclose(one.positions_mm[k], two.positions_mm[k], rtol=0.0, atol=tol)
    # not yet to 1e-6: on the pair at the nominal blur the significances still differ by
    # up to 1.6 % between 1 and 2 threads (25.74/25.78σ, 8.04/7.91σ; source not found, ADR
    # 0109) — far from any threshold, and the decisions above are the same
    np.testing.assert_allclose(two.significance, one.significance, rtol=0.05)
    np.testing.assert_allclose(two.depth_interval_mm, one.depth_interval_mm, rtol=0.0,
                               atol=1e-6 * 400.0)
