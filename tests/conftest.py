"""Suite-wide fixtures: emulator URL handlers registered, a clean emulator registry.

The suite needs no display and no environment variables. Before anything imports Qt,
matplotlib or a BLAS, this module chooses:

- Qt's ``offscreen`` platform unless ``QT_QPA_PLATFORM`` is set: on a machine without an X
  server (an SSH login, a container) Qt would otherwise abort the whole run when the first
  GUI test creates its ``QApplication``; on a desktop it keeps test windows off the screen.
  The real-display smoke test starts its own X server and sets the platform itself.
- matplotlib's ``Agg`` backend unless ``MPLBACKEND`` is set.
- one BLAS/OpenMP thread per process unless set: the suite runs two processes per core
  (pytest-xdist), and a threaded OpenBLAS in each of them oversubscribes the cores (on a
  loaded 2-core box a 1500×81 SVD went from 4 ms to 1.2 s).

``.ci/run`` sets the same values; there they are a speed-up, not a condition.

Bytecode caches are written even where ``PYTHONDONTWRITEBYTECODE`` is set (they are
ignored by git): without them every xdist worker rewrites the asserts of every test
module and compiles every project module again, and so does every server and CLI
subprocess a test starts — measured, collection alone took 25 s of CPU per worker without
the caches and 7–11 s with them.
"""

from __future__ import annotations

import os
import sys

sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # the workers and subprocesses too

_DEFAULT_ENVIRONMENT = {
    "QT_QPA_PLATFORM": "offscreen",
    "MPLBACKEND": "Agg",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
for _name, _value in _DEFAULT_ENVIRONMENT.items():
    os.environ.setdefault(_name, _value)

import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from drivers.transport import add_url_handler_package  # noqa: E402
from hw_mocks import registry  # noqa: E402
from hw_mocks.sim.world import reset_worlds  # noqa: E402

add_url_handler_package("hw_mocks.urlhandler")

# Property tests: no per-example deadline (a loaded 2-core CI box is not a slow parser), and
# in CI a derandomised, replayable sequence of examples, like every other seeded test.
settings.register_profile(
    "scatterlab", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "ci", parent=settings.get_profile("scatterlab"), derandomize=True, database=None)
settings.load_profile("ci" if os.environ.get("CI") else "scatterlab")


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: two test processes per core, at most 16.

    Much of the suite waits rather than computes (emulated stages moving in scaled real
    time, subprocesses, Dask workers starting): with one process per core the 2-core box
    stayed at a load of 1.6–1.9. ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still overrides this.
    """
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None  # xdist's own hook reads it
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return min(16, 2 * (cores or 1))


@pytest.fixture(autouse=True)
def _fresh_emulators():
    """Every test starts with freshly powered emulated devices and no virtual worlds."""
    registry.reset()
    reset_worlds()
    yield
    registry.reset()
    reset_worlds()
