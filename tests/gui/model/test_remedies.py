"""Remedies in the GUI's words: the shared layers' messages name GUI controls."""

from __future__ import annotations

import pytest

from drivers.errors import NotHomedError, StateError
from gui.model.remedies import ANALYSIS_CONTROLS, event_for_gui, for_gui
from instrument.run.events import Fault, Paused, RunFinished


def test_unhomed_jog_names_the_home_button():
    err = NotHomedError("axis is not homed", device="detector_theta", command="move_to",
                        hint="call home() first")
    assert for_gui(str(err)) == ("detector_theta: axis is not homed. Home this axis first "
                                 "(Home button, or Home all)")
    off = StateError("axis is disabled", device="camera_z", command="move_to",
                     hint="call enable() first")
    assert "Home button" in for_gui(str(off)) and "enable()" not in for_gui(str(off))


@pytest.mark.parametrize("text", [
    "disk nearly full: 3.0 MiB free in /r, the run keeps at least 64.0 MiB free (point "
    "needs 0.20 MiB); free space, then `scatterlab resume`",
    "no room for the next point in /r/a.h5: No space left on device; free space, then "
    "`scatterlab resume`",
])
def test_disk_full_says_press_retry(text):
    out = for_gui(text)
    assert out.endswith("free space, then press Retry the point (Run dock)")
    assert "scatterlab" not in out and out.startswith(text.split(";")[0])


def test_fit_warnings_name_the_analysis_controls():
    w = for_gui("profile detector distance; camera_z was not homed, so its position is "
                "unknown (assumed 0: give --distance-mm if it is elsewhere)")
    assert "set Distance (mm) in the Analysis tab's options if it is elsewhere" in w
    s = for_gui("the incident power (1e-3 W, profile; set it with --incident-power-u)")
    assert s.endswith("set it with Incident power uncertainty in the Analysis tab's "
                      "options)")
    d = for_gui("the receiver distance (set it with --distance-u-mm)")
    assert "Distance uncertainty (mm)" in d and "--" not in d
    assert set(ANALYSIS_CONTROLS) >= {"--distance-mm", "--distance-u-mm",
                                      "--incident-power-u"}


def test_events_keep_their_values_and_change_only_text():
    f = Fault("storage", "disk nearly full: 1 MiB; free space, then `scatterlab resume`",
              "pause", 27)
    g = event_for_gui(f)
    assert g.index == 27 and g.device == "storage" and g.action == "pause"
    assert g.cause.endswith("press Retry the point (Run dock)")
    p = event_for_gui(Paused("storage: free space, then `scatterlab resume`", 4))
    assert "Retry" in p.reason and p.index == 4
    end = RunFinished("paused", 3, 9, 0, "/r/a.h5", 1.0,
                      "the run file was closed at the storage error; `scatterlab resume` "
                      "continues it")
    assert event_for_gui(end).message.endswith("Resume this run (Runs dock) continues it")
    same = Fault("camera", "timeout", "retry 1/3", 2)
    assert event_for_gui(same) is same
    assert for_gui("") == "" and for_gui("nothing to map") == "nothing to map"
