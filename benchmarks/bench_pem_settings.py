"""PEM polarimetry: the condition number of the minimal fixed settings.

For each choice of the source polariser's two settings (the modulator fixed at 45°), the
four analyser-retarder angles (a quarter-wave plate before a polariser at 0°) that give
the smallest condition number of the stacked DC/1f/2f instrument matrix, searched over a
grid; then, for the default settings, κ against the modulator's amplitude A (J₀(A) = 0 at
2.405 rad; J₁ peaks at 1.84 rad, J₂ at 3.05 rad).

Run: ``python benchmarks/bench_pem_settings.py [--grid-deg 7.5]``
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from analysis.polarimetry.pem import pem_condition_number, pem_settings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid-deg", type=float, default=7.5)
    parser.add_argument("--amplitude", type=float, default=2.405)
    args = parser.parse_args()
    grid = np.arange(-90.0, 90.0, args.grid_deg)
    print(f"amplitude {args.amplitude} rad; analyser retarder angles over a "
          f"{args.grid_deg}° grid")
    print("source polariser   best analyser retarder angles (deg)   κ")
    for gens in ((0.0, 45.0), (0.0, -45.0), (0.0, 22.5), (0.0, 67.5)):
        best = (np.inf, ())
        for ans in itertools.combinations(grid, 4):
            k = pem_condition_number(pem_settings(gens, ans), amplitude_rad=args.amplitude)
            best = min(best, (k, ans))
        angles = ", ".join(f"{a:g}" for a in best[1])
        print(f"{gens!s:<18} {angles:<37} {best[0]:.2f}")
    print("\nκ of the default settings against the amplitude")
    for amp in (1.0, 1.84, 2.405, 3.05, 3.5):
        kappa = pem_condition_number(pem_settings(), amplitude_rad=amp)
        print(f"  A = {amp:5.3f} rad  κ = {kappa:.2f}")


if __name__ == "__main__":
    main()
