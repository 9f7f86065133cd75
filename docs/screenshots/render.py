"""Render the screenshots on the simulated bench: ``python docs/screenshots/render.py
[FOLDER] [--only gui|dashboard]`` (default: this folder, both).

The GUI's pictures (offscreen: ``QT_QPA_PLATFORM=offscreen``), then the bench server's web
dashboard in a headless Chromium (Debian's ``chromium`` package, driven by Playwright).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", nargs="?", default=str(Path(__file__).resolve().parent))
    p.add_argument("--only", choices=("gui", "dashboard"), default=None)
    args = p.parse_args(argv)
    if args.only in (None, "gui"):
        from gui.screenshots import main as render_gui
        render_gui(args.folder)
    if args.only in (None, "dashboard"):
        from instrument.server.dashboard.chromium import chromium_missing
        from instrument.server.dashboard.screenshots import render_dashboard
        if (why := chromium_missing()) is not None:
            print(why.replace("dashboard browser tests skipped", "dashboard pictures not "
                              "rendered"), file=sys.stderr)
            return 1
        for name, path in render_dashboard(args.folder).items():
            print(f"{name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
