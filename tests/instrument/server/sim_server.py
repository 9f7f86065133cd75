"""Child process for the end-to-end tests: ``scatterlab serve`` on an emulated bench, with
an optional device fault injected from inside the bench (where the emulators live).

``python -m tests.instrument.server.sim_server ARGS...`` takes the arguments of
``scatterlab serve``. With ``SCATTERLAB_TEST_FAULT=scheme:name:after`` in the environment,
the link of the emulated controller ``scheme://name`` is cut at its next exchange once
point ``after`` is stored (on the engine's worker thread, so it strikes during the run
however fast the machine is), and plugged back in when the run pauses for it: the
operator's answer (retry, skip, abort) then decides.

With ``SCATTERLAB_TEST_KILL=run:point`` the server kills itself (SIGKILL, as ``kill -9``
would) on the engine's worker thread once point ``point`` of the ``run``-th run it
started is stored: a kill at a chosen place however fast the machine is (the second pass
of a two-pass lobe plan, for instance).
"""

from __future__ import annotations

import os
import signal
import sys

from hw_mocks import registry
from hw_mocks.faults import FaultKind
from instrument.cli import main
from instrument.run import events as ev
from instrument.server import main as server_main
from instrument.server.service import BenchService


class FaultyService(BenchService):
    def __init__(self, *args, **kw) -> None:
        scheme, name, after = os.environ["SCATTERLAB_TEST_FAULT"].split(":")
        self._target = (scheme, name)
        self._fault_after = int(after)
        self._armed = True
        super().__init__(*args, **kw)

    def _on_engine_event(self, event) -> None:
        super()._on_engine_event(event)
        faults = registry.get(*self._target).faults
        if (self._armed and isinstance(event, ev.PointCompleted)
                and event.index >= self._fault_after):
            self._armed = False
            faults.schedule(FaultKind.DISCONNECT, nth=1)  # the cable is pulled
        elif isinstance(event, ev.Paused):
            faults.clear()  # plugged back in, for the operator's answer


class KilledService(BenchService):
    def __init__(self, *args, **kw) -> None:
        run, point = os.environ["SCATTERLAB_TEST_KILL"].split(":")
        self._kill_at = (int(run), int(point))
        self._n_runs = 0
        super().__init__(*args, **kw)

    def _on_engine_event(self, event) -> None:
        super()._on_engine_event(event)
        if isinstance(event, ev.RunStarted):
            self._n_runs += 1
        elif isinstance(event, ev.PointCompleted) and \
                (self._n_runs, event.index) >= self._kill_at:
            os.kill(os.getpid(), signal.SIGKILL)


if __name__ == "__main__":
    special = FaultyService if os.environ.get("SCATTERLAB_TEST_FAULT") else \
        KilledService if os.environ.get("SCATTERLAB_TEST_KILL") else None
    if special is not None:
        serve = server_main.serve

        def serve_special(*args, **kw):
            return serve(*args, make_service=special, **kw)

        server_main.serve = serve_special
    sys.exit(main(["serve", *sys.argv[1:]]))
