"""A seeded lock-in scan's data are a function of the seed and the plan only.

The same plan on the emulated spectral bench (SR830 firmware with a chopped photodiode,
SC10, FW102C; real drivers through the engine) is run twice with the same lock-in seed:
once as it comes, once on a slow host, every lock-in reply arriving 20 ms late on the
wire (a seeded ``DELAY`` fault on every frame) while a thread burns the CPU beside the
engine. Every lock-in column of the two run files must be identical to the bit. (That
another seed reads other values: tests/hw_mocks/test_sr830_host_paced.py.)

Before the emulated SR830 took its time from the host's waits (``clock=host``, ADR 0014
amendment), its output filter and noise ran on the wall clock: the noise drawn between two
queries, and the state the filter had reached, depended on how long the host took between
them, and these two runs differed in every reading.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np
import pytest

from hw_mocks import registry
from hw_mocks.faults import FaultKind
from hw_mocks.sim.world import reset_worlds
from hw_mocks.urlhandler.protocol_simsr830 import make_emulator
from instrument.cli import main
from instrument.run.layout import DETECTOR_FIELDS
from instrument.run.runfile import read_run
from tests.instrument.pipelines.brdf.test_lockin_pulls import PLAN as PULLS_PLAN
from tests.instrument.pipelines.brdf.test_lockin_pulls import lockin_profile

#: The pull test's scan of a Lambertian sample (550 nm filter, per-point darks, 4
#: snapshots), at two of its angles.
PLAN = PULLS_PLAN.replace("theta_r = [-60, -40, -10, 0, 10, 20, 40, 50, 60, 70]",
                          "theta_r = [-40, 60]")

LOCKIN_COLUMNS = [f for f in DETECTOR_FIELDS if f.startswith("lockin_")]


def _profile(seed: int) -> str:
    # a 10 ms time constant: the same filter physics in a third of the settling time
    text = lockin_profile("lambert", "{ rho = 0.5 }", seed)
    assert "time_constant_s = 0.03" in text and "clock=host" in text
    return text.replace("time_constant_s = 0.03", "time_constant_s = 0.01")


def _lockin_url(profile: str) -> str:
    (url,) = re.findall(r'"(simsr830://[^"]+)"', profile)
    return url


def _run(tmp_path: Path, name: str, profile: str) -> dict[str, np.ndarray]:
    bench = tmp_path / f"{name}.toml"
    bench.write_text(profile, encoding="utf-8")
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    out = tmp_path / name
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    run = read_run(path)
    assert run.n_points == 2
    return {c: np.asarray(getattr(run, c), dtype=float) for c in LOCKIN_COLUMNS}


def _power_on_again() -> None:
    """Every emulated device switched off and on again (a fresh emulator per URL)."""
    registry.reset()
    reset_worlds()


@pytest.mark.slow  # two lock-in scans with real settling waits: ~18 s (ADR 0021)
def test_a_seeded_lock_in_scan_gives_the_same_data_on_a_slow_host(tmp_path):
    profile = _profile(7)
    quiet = _run(tmp_path, "quiet", profile)

    _power_on_again()
    # The lock-in the run will open, made beforehand so that its replies can be delayed.
    url = _lockin_url(profile)
    scheme, name, options = registry.parse_url(url)
    lockin = registry.get_or_create(scheme, name, make_emulator, options)
    lockin.faults.randomly(FaultKind.DELAY, probability=1.0, delay_s=0.02)
    stop = threading.Event()

    def burn() -> None:
        while not stop.is_set():
            sum(range(10_000))

    hog = threading.Thread(target=burn, name="cpu-hog", daemon=True)
    hog.start()
    try:
        slow = _run(tmp_path, "slow", profile)
    finally:
        stop.set()
        hog.join(timeout=60)
    assert lockin.faults.frames_seen > 50  # the delays did happen

    # noisy readings (each point's snapshots differ), not a noiseless emulator
    assert np.all(quiet["lockin_r_v"] > 0) and np.all(quiet["lockin_u_r_v"] > 0)
    for column in LOCKIN_COLUMNS:
        np.testing.assert_array_equal(slow[column], quiet[column], err_msg=column)

