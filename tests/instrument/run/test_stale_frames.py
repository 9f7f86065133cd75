"""The engine never records a frame exposed before the scene changed.

The simulated camera's ``stale=N`` option makes it behave like a V4L2 driver queue holding
N frames: without :meth:`Camera.invalidate` after every move and every switch of the light,
each point would record the frames of an earlier geometry or lighting. The same scan with
and without that queue must therefore give the same signals (within the sensor noise).
"""

from __future__ import annotations

import h5py
import numpy as np

from instrument.bench.profile import load_profile
from instrument.cli import main
from tests.instrument.cli.test_cli_run import PLAN


def _scan(tmp_path, name: str, stale: int) -> np.ndarray:
    text = load_profile("sim").source_text.replace(
        'url = "simcam://camera?world=sim&seed=1"',
        f'url = "simcam://camera?world=sim&seed=1&stale={stale}"')
    assert f"stale={stale}" in text
    bench = tmp_path / f"{name}.toml"
    bench.write_text(text)
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    out = tmp_path / name
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    with h5py.File(next(out.glob("*.h5")), "r") as f:
        return f["entry/points/signal"][:]


def test_stale_driver_queue_never_reaches_the_data(tmp_path, capsys):
    fresh = _scan(tmp_path, "fresh", stale=0)
    queued = _scan(tmp_path, "queued", stale=3)
    capsys.readouterr()
    # Three detector angles (10, 30, 50 deg) give clearly different signals, so a frame
    # from the previous point, or a lit frame used as the dark, would be off by far more
    # than the shot noise of these ~1e5-electron signals (< 1 %).
    assert np.all(fresh > 0)
    assert np.ptp(fresh) / fresh.mean() > 0.05
    np.testing.assert_allclose(queued, fresh, rtol=0.02)
