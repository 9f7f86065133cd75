"""What a fault means and which recovery choices apply (Qt-free)."""

from __future__ import annotations

from gui.model.faults import FaultLog, PauseKind, Recovery, describe, recovery_for
from instrument.run.events import Fault, Paused


def test_severity_and_meaning_follow_the_action():
    assert describe(Fault("detector_theta", "timeout", "retry 1/2", 3)).severity == "info"
    rehome = describe(Fault("sample_theta", "x", "rehome", 3))
    assert rehome.severity == "warning" and "re-homes" in rehome.meaning
    pause = describe(Fault("detector_theta", "disconnected", "pause", 4))
    # the plan index is 0-based, the operator's count (the progress) from 1
    assert pause.severity == "error" and "paused at point 5" in pause.meaning
    assert describe(Fault("camera", "x", "skip point", 5)).meaning.startswith("point 6")


def test_recovery_choices():
    fault = Fault("detector_theta", "disconnected", "pause", 4)
    after = recovery_for(Paused("detector_theta: disconnected", 4), fault)
    assert after.kind is PauseKind.DEVICE_FAULT
    assert after.choices == (Recovery.RETRY, Recovery.SKIP, Recovery.ABORT)
    storage = recovery_for(Paused("storage: disk full", 7),
                           Fault("storage", "disk full", "pause", 7))
    assert storage.kind is PauseKind.STORAGE_FAULT and Recovery.SKIP not in storage.choices
    mine = recovery_for(Paused("paused by the operator", 9), fault)  # an older fault
    assert mine.kind is PauseKind.OPERATOR
    assert mine.choices == (Recovery.RESUME, Recovery.ABORT)


def test_the_log_is_bounded():
    log = FaultLog(maxlen=3)
    for k in range(5):
        log.add(Fault("x", "c", "retry 1/2", k))
    assert log.total == 5 and [r.index for r in log.rows] == [2, 3, 4]
