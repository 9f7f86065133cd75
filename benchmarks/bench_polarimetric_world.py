"""CPU cost of one emulated power-meter reading: the scalar sample against the Stokes world.

Builds the virtual bench of a built-in profile (its ``[simulation]`` table, the axes as
constant roles so no emulator runs) and times ``VirtualBench.optical_power_w`` at
``--n`` world states (process CPU seconds, which a loaded shared box stretches less than
wall time): on ``sim`` the detector arm steps (each reading a new state), on
``sim-polarimetric`` the source-arm retarder steps as in a DRR scan. Run it against
another checkout with ``PYTHONPATH=/path/to/checkout`` to compare the scalar bench before
and after a change.

    python benchmarks/bench_polarimetric_world.py --bench sim
    python benchmarks/bench_polarimetric_world.py --bench sim-polarimetric
"""

from __future__ import annotations

import argparse
import time

from hw_mocks.sim.world import VirtualBench
from instrument.bench.devices import simulation_config
from instrument.bench.profile import load_profile

ROLES = {"sample_theta": 50.0, "detector_theta": 100.0, "psg_polariser": 0.0,
         "psa_polariser": 0.0, "psg_retarder": 0.0, "psa_retarder": 0.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench", default="sim")
    parser.add_argument("--n", type=int, default=10)
    args = parser.parse_args()
    profile = load_profile(args.bench)
    _name, config = simulation_config(profile)
    config = dict(config)
    config["roles"] = dict(ROLES)
    config.pop("filter_wheel", None)  # no emulator: the beam straight to the sample
    config.pop("shutter", None)
    config["power_meter"] = {k: v for k, v in config.get("power_meter", {}).items()
                             if k != "url"}
    world = VirtualBench.from_config("bench", config)
    world.update_source(on=True)
    polarimetric = getattr(world, "optics", None) is not None
    world.optical_power_w()  # imports and first-use costs out of the timing
    start = time.process_time()
    for k in range(args.n):
        if polarimetric:
            world.set_role("psg_retarder", 5.0 * (k + 1))
            world.set_role("psa_retarder", 25.0 * (k + 1) % 360.0)
        else:
            world.set_role("detector_theta", 100.0 + 0.5 * (k + 1))
        world.optical_power_w()
    per = (time.process_time() - start) / args.n
    print(f"{args.bench}: {per * 1e3:.1f} ms CPU per power-meter reading "
          f"({args.n} world states)")


if __name__ == "__main__":
    main()
