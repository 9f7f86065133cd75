"""The operator's log without Qt."""

from __future__ import annotations

import logging

from gui.model.logbook import LogBook, LogBookHandler, from_event, from_result
from gui.model.session import CommandResult, MoveTo
from instrument.run.events import Fault, PointCompleted, RunFinished


def test_entries_filter_by_level_and_text_and_stay_bounded():
    book = LogBook(maxlen=3)
    book.log("info", "engine", "run started")
    book.log("warning", "fit", "camera_z not homed, distance assumed")
    book.log("error", "bench", "detector_theta: disconnected")
    book.log("info", "engine", "resumed")
    assert book.total == 4 and len(book.entries()) == 3
    assert [e.source for e in book.entries(min_level="warning")] == ["fit", "bench"]
    assert [e.source for e in book.entries(text="CAMERA_Z")] == ["fit"]
    assert "WARNING fit: camera_z not homed" in book.as_text(min_level="warning")


def test_events_and_results_become_entries():
    f = from_event(Fault("detector_theta", "disconnected", "pause", 3))
    assert f.level == "error" and "disconnected → pause" in f.message
    assert from_event(Fault("x", "c", "retry 1/2", 1)).level == "warning"
    assert from_event(PointCompleted(0, "s", "ok", {}, None, 1, 1, 1, 0)) is None
    assert from_event(RunFinished("aborted", 1, 2, 0, "p", 1.0, "")).level == "warning"
    assert from_result(CommandResult(MoveTo("a", 1), True, "moving")) is None
    refused = from_result(CommandResult(MoveTo("a", 1), False, "beam", refused=True))
    assert refused.level == "warning" and refused.source == "bench"


def test_python_logging_reaches_the_book():
    book = LogBook()
    seen = []
    handler = LogBookHandler(book, on_entry=seen.append)
    logger = logging.getLogger("drivers.test_logbook")
    logger.addHandler(handler)
    try:
        logger.warning("reply %d dropped", 7)
    finally:
        logger.removeHandler(handler)
    assert seen[0].message == "reply 7 dropped" and seen[0].level == "warning"
    assert book.entries()[0].source == "drivers.test_logbook"
