"""Child process for the client window's start-up test: which modules the window's first
redraws import on the GUI thread.

``python -m tests.gui.first_redraw URL``: opens the client window on the server at URL,
notes the modules imported so far, then runs the event loop until the window has built its
run browser (on the redraw that first knows the server's runs folder). Prints one JSON
line: the modules imported in between, and whether ``scipy.stats`` was imported before
the window showed. Every wait polls a condition under a generous limit.
"""

from __future__ import annotations

import contextlib
import json
import sys

from PySide6.QtWidgets import QApplication

from tests.waiting import wait_for

#: Seconds the window may take to connect and build its run browser on a loaded machine.
TIMEOUT_S = 120.0


def main(url: str) -> int:
    app = QApplication([])
    from gui.qt.client_window import ClientWindow

    window = ClientWindow(url)
    before = set(sys.modules)
    window.show()

    def browser_built() -> bool:
        app.processEvents()
        return window.browser is not None

    # tests.waiting: poll a condition, the limit only bounds a hang
    with contextlib.suppress(AssertionError):  # not built: the JSON line says so
        wait_for(browser_built, TIMEOUT_S, "the run browser")
    print(json.dumps({"browser": window.browser is not None,
                      "stats_before_show": "scipy.stats" in before,
                      "imported": sorted(set(sys.modules) - before)}))
    window.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
