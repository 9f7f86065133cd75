"""An in-plane BRDF scan of the simulated bench from Python, fitted and plotted.

    .venv/bin/python examples/scripting/inplane_fit.py [RUNS_DIR]

Only the public facade is imported (docs/guide/scripting.md).
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from instrument import fit, open_bench, plans

runs = sys.argv[1] if len(sys.argv) > 1 else "runs"
plan = plans.in_plane(theta_i=[30.0], theta_r=range(-70, 81, 10), skip_beam_points=True,
                      sample="sim-grey",
                      acquisition={"mode": "auto", "dark": "per_point", "hdr": True})
with open_bench("sim", runs_dir=runs) as bench:
    run = bench.run(plan).result()
result = fit(run.path)
print(f"{result.result.chosen}: {result.result.verdict}")
ds = run.to_xarray()
fig, ax = plt.subplots()
signed = ds["theta_r"].where(ds["phi_r"] == 180.0, -ds["theta_r"])  # + on the specular side
ax.errorbar(signed, ds["brdf"], yerr=ds["u_brdf"], fmt="o")
ax.set_xlabel("signed θr (deg)")
ax.set_ylabel(f"BRDF ({ds['brdf'].attrs['units']})")
fig.savefig(f"{runs}/{run.run_id}_brdf.png")
print(f"figure: {runs}/{run.run_id}_brdf.png")
