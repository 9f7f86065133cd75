"""Render the GUI's screenshots on the simulated bench: ``python docs/screenshots/render.py
[FOLDER]`` (default: this folder). Offscreen: ``QT_QPA_PLATFORM=offscreen``."""

from __future__ import annotations

import sys

from gui.screenshots import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
