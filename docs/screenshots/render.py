"""Render the screenshots on the simulated bench: ``python docs/screenshots/render.py
[FOLDER] [--only gui|polarimetric|dashboard] [--bench sim-type-i]`` (default: this folder,
all). ``--bench sim-type-i`` renders the GUI's type (i) pictures only (``bench_type_i.png``,
``goniometer_type_i.png``); ``--only polarimetric`` the plan editor's polarimetric trade
on ``sim-polarimetric`` only (``plan_editor_polarimetric.png``).

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
    p.add_argument("--only", choices=("gui", "polarimetric", "dashboard"), default=None,
                   help="gui: the GUI's pictures (the polarimetric one included); "
                   "polarimetric: the plan editor's polarimetric trade only")
    p.add_argument("--bench", choices=("sim", "sim-type-i"), default="sim",
                   help="sim-type-i: the GUI's type (i) pictures only")
    args = p.parse_args(argv)
    if args.only in (None, "gui"):
        from gui.screenshots import main as render_gui
        render_gui(args.folder, args.bench)
    if args.only in (None, "gui", "polarimetric") and args.bench == "sim":
        from gui.screenshots import render_polarimetric_planner
        print(f"plan_editor_polarimetric: {render_polarimetric_planner(args.folder)}")
    if args.only in (None, "dashboard") and args.bench == "sim":
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
