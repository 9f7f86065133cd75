"""``scatterlab gui``: which window each set of options opens.

``--in-process`` opens the full in-process window (goniometer drawing, camera settings,
per-device panels) with the engine in the GUI; without it the client window on a server
(docs/decisions/0084)."""

from __future__ import annotations

import sys
import types

import pytest

from instrument.cli import build_parser


def _args(*argv: str):
    return build_parser(["gui", *argv]).parse_args(["gui", *argv])


def test_the_in_process_flag_is_parsed_and_selects_the_full_window(monkeypatch, capsys):
    import instrument.cli.gui as cli_gui

    assert cli_gui.gui_call(_args("--in-process", "--bench", "sim", "--out", "d")) == \
        ("main_in_process", {"bench": "sim", "out": "d"})
    assert cli_gui.gui_call(_args("--server", "http://127.0.0.1:1")) == \
        ("main", {"bench": None, "out": None, "server": "http://127.0.0.1:1"})

    # run() calls the named function of the GUI's entry module, and nothing else
    calls: list[tuple[str, dict]] = []
    entry = types.ModuleType("gui_entry_under_test")
    entry.main = lambda **kw: calls.append(("main", kw)) or 0
    entry.main_in_process = lambda **kw: calls.append(("main_in_process", kw)) or 0
    monkeypatch.setitem(sys.modules, entry.__name__, entry)
    monkeypatch.setattr(cli_gui, "GUI_ENTRY", entry.__name__)
    assert cli_gui.run(_args("--in-process", "--out", "d")) == 0
    assert calls == [("main_in_process", {"bench": None, "out": "d"})]

    # options that contradict it are refused, saying what to do, before any window
    assert cli_gui.run(_args("--in-process", "--server", "http://127.0.0.1:1")) == 2
    assert "drop --server" in capsys.readouterr().err
    assert cli_gui.run(_args("--in-process", "--stop-server")) == 2
    assert "choose one" in capsys.readouterr().err
    assert len(calls) == 1

    # the real entry module has the function, taking those arguments
    import inspect

    import gui.app

    name, kwargs = cli_gui.gui_call(_args("--in-process", "--bench", "sim"))
    inspect.signature(getattr(gui.app, name)).bind(**kwargs)

    help_text = build_parser(["gui"])._subparsers._group_actions[0].choices["gui"] \
        .format_help()
    assert "--in-process" in help_text and "region of interest" in help_text


@pytest.mark.timeout(300)
def test_main_in_process_opens_the_full_window_on_a_connected_bench(
        qtbot, monkeypatch, tmp_path, settings, fast_bench_file):
    import gui.app
    from gui.qt.main_window import MainWindow
    from tests.gui.conftest import flush_deleted

    shown = []
    # the event loop is the test's: the window is kept instead of run until it closes
    monkeypatch.setattr(gui.app, "_exec", lambda app, w, after=None: shown.append(w) or 0)
    assert gui.app.main_in_process(bench=fast_bench_file(), out=str(tmp_path / "runs"),
                                   settings=settings) == 0
    (w,) = shown
    try:
        assert isinstance(w, MainWindow)
        for dock in ("bench", "goniometer"):
            assert dock in w.docks
        qtbot.waitUntil(lambda: w.session.connected and bool(w.bench_panel.panels),
                        timeout=120_000)
        assert settings.value("runs_dir") == str(tmp_path / "runs")
    finally:
        w.close()
        w.session.close(20)
        w.deleteLater()
        flush_deleted()
