"""Remedies in the GUI's words: every action a message names is one the GUI can do.

Drivers, the engine, the run storage and the analysis pipelines are shared with the
command line, so their messages name a Python call (``call home() first``), a command
(``scatterlab resume``) or a CLI option (``--distance-mm``). Shown in the GUI, that remedy
is one the operator cannot carry out from the window. :func:`for_gui` rewrites a message
so that it names the button, field or control that does the same thing; the rest of the
message (the device, the value, the limit) is left as it is. :func:`event_for_gui` does the
same for an engine event's text fields.

The table is explicit, one entry per remedy the shared layers give: a message nobody
listed here keeps its words (better an unmapped CLI hint than a wrong GUI one).
"""

from __future__ import annotations

import re
from dataclasses import fields, is_dataclass, replace
from typing import Any

__all__ = ["ANALYSIS_CONTROLS", "REMEDIES", "event_for_gui", "for_gui"]

#: The analysis options of ``scatterlab fit`` → the control of the Analysis tab's options
#: that sets the same value (gui.qt.analysis_options builds them with these labels).
ANALYSIS_CONTROLS: dict[str, str] = {
    "--distance-mm": "Distance (mm)",
    "--distance-u-mm": "Distance uncertainty (mm)",
    "--incident-power-u": "Incident power uncertainty",
    "--models": "Candidate models",
    "--detector": "Detector",
}

_OPTION = "|".join(re.escape(o) for o in sorted(ANALYSIS_CONTROLS, key=len, reverse=True))

#: (pattern, replacement) in order; a replacement may use the pattern's groups.
REMEDIES: tuple[tuple[re.Pattern[str], str], ...] = (
    # drivers (drivers/base.py): the hint after the command
    (re.compile(r"axis is not homed \[command [\w.]+\]\. call home\(\) first"),
     "axis is not homed. Home this axis first (Home button, or Home all)"),
    (re.compile(r"axis is disabled \[command [\w.]+\]\. call enable\(\) first"),
     "axis is disabled. Home this axis (Home button) to enable and home it"),
    # run storage (instrument/run/storage.py): the run pauses; Retry continues it
    (re.compile(r"free space, then `scatterlab resume`"),
     "free space, then press Retry the point (Run dock)"),
    # the engine and recovery: a run that ended early
    (re.compile(r"`scatterlab resume` (continues|repairs) it"),
     r"Resume this run (Runs dock) \1 it"),
    (re.compile(r"continue (?:it|the run) with:?\s*scatterlab resume \S+"),
     "continue it with Resume this run (Runs dock)"),
    # the fit pipeline's warnings (instrument/pipelines/brdf/reduce.py)
    (re.compile(rf"give ({_OPTION})"), r"set «\1»"),
    (re.compile(rf"set it with ({_OPTION})"), r"set it with «\1»"),
)


def _controls(text: str) -> str:
    """«--option» placeholders → the GUI control's name, in the Analysis tab."""
    return re.sub(r"«([^»]+)»", lambda m: f"{ANALYSIS_CONTROLS[m.group(1)]} in the "
                  "Analysis tab's options", text)


def for_gui(text: str) -> str:
    """``text`` with every remedy the GUI offers named as the GUI's control."""
    if not text:
        return text
    for pattern, repl in REMEDIES:
        text = pattern.sub(repl, text)
    return _controls(text)


def event_for_gui(ev: Any) -> Any:
    """An engine event (a frozen dataclass) with its text fields through :func:`for_gui`;
    the same object when nothing changes."""
    if not is_dataclass(ev):
        return ev
    changes = {}
    for f in fields(ev):
        if f.name in ("cause", "reason", "message"):
            value = getattr(ev, f.name)
            if isinstance(value, str):
                new = for_gui(value)
                if new != value:
                    changes[f.name] = new
    return replace(ev, **changes) if changes else ev
