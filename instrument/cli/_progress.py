"""Console progress for runs: a bar with ETA, fault lines and an end summary."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from instrument.cli._format import fmt_s
from instrument.run.events import (
    AxisHomed,
    Event,
    Fault,
    Paused,
    PointCompleted,
    Progress,
    Resumed,
    RunFinished,
    RunStarted,
)
from instrument.run.runfile import RunFileError, RunSummary, read_summary

__all__ = ["ConsoleProgress", "fmt_s", "print_summary"]


class ConsoleProgress:
    """Event subscriber printing to a terminal (called on the engine's worker thread)."""

    def __init__(self, stream: TextIO | None = None, *, width: int = 30,
                 min_interval_s: float = 0.1) -> None:
        self.stream = stream or sys.stdout
        self.width = width
        self.min_interval_s = min_interval_s
        self._last = 0.0
        self._live = ""
        self.faults = 0
        self.finished: RunFinished | None = None
        self._tty = getattr(self.stream, "isatty", lambda: False)()

    def _line(self, text: str) -> None:
        if self._tty:
            self.stream.write("\r\033[K" + text + "\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def __call__(self, ev: Event) -> None:
        match ev:
            case RunStarted():
                resumed = f" (resuming: {ev.n_done} already done)" if ev.n_done else ""
                self._line(f"run {ev.run_id}: {ev.n_total} points{resumed}, "
                           f"estimated {fmt_s(ev.estimated_s)}")
                self._line(f"  writing {ev.path}")
            case PointCompleted():
                parts = []
                if ev.angles is not None:
                    parts.append(f"θi={ev.angles[0]:.1f}° θr={ev.angles[2]:.1f}°")
                if ev.signal == ev.signal:
                    parts.append(f"camera {ev.signal:.3g} DN/µs")
                if ev.power_w == ev.power_w:
                    parts.append(f"power meter {ev.power_w:.3g} W")
                if ev.status != "ok":
                    parts.append(ev.status.upper())
                self._live = " ".join(parts)
            case Progress():
                now = time.monotonic()
                if now - self._last < self.min_interval_s and ev.n_done < ev.n_total:
                    return
                self._last = now
                frac = ev.n_done / max(1, ev.n_total)
                bar = "#" * int(frac * self.width)
                text = (f"[{bar:<{self.width}}] {ev.n_done}/{ev.n_total} {frac:4.0%} "
                        f"elapsed {fmt_s(ev.elapsed_s)} ETA {fmt_s(ev.eta_s)}  {self._live}")
                if self._tty:
                    self.stream.write("\r\033[K" + text)
                    self.stream.flush()
                elif ev.n_done == ev.n_total or now - getattr(self, "_plain", 0) > 5:
                    self._plain = now
                    self._line(text)
            case AxisHomed():
                self._line(f"  {ev.device}: homed in {fmt_s(ev.elapsed_s)}, at "
                           f"{ev.position:.6g}")
            case Fault():
                self.faults += 1
                where = "" if ev.index is None else f" at point {ev.index}"
                self._line(f"  fault{where}: {ev.device}: {ev.cause} -> {ev.action}")
            case Paused():
                self._line(f"  paused: {ev.reason}")
            case Resumed():
                self._line("  resumed")
            case RunFinished():
                self.finished = ev
                if self._tty:
                    self.stream.write("\n")


def print_summary(ev: RunFinished, faults: int, stream: TextIO | None = None) -> None:
    """What happened and what the run file holds (only what the bench recorded)."""
    out = stream or sys.stdout
    print(f"\nrun {ev.status}: {ev.n_done} of {ev.n_total} points in {fmt_s(ev.elapsed_s)}"
          + (f", {ev.n_skipped} skipped" if ev.n_skipped else "")
          + (f", {faults} fault event(s)" if faults else ""), file=out)
    if ev.message:
        print(f"  note: {ev.message}", file=out)
    print(f"run file: {ev.path}", file=out)
    try:
        s = read_summary(ev.path)
    except (OSError, KeyError, RunFileError) as err:
        print(f"  (could not read the file back: {err}; `scatterlab resume {ev.path}` "
              "repairs it)", file=out)
    else:
        print(f"  holds: {holdings(s)}", file=out)
        print("  read it with h5py: h5py.File(path)['entry/points'] and ['entry/data/frames']",
              file=out)
        if s.lost:
            print(f"  the frames of point(s) {', '.join(map(str, s.lost))} are lost (status 2, "
                  f"left out of analysis); measure them again with: scatterlab resume "
                  f"--remeasure-lost {ev.path}", file=out)
    if ev.status != "finished":
        print(f"  continue it with: scatterlab resume {ev.path}", file=out)


def holdings(s: RunSummary) -> str:
    """What a run file holds, in one line: sample, points and what was recorded at each,
    frames, provenance, size (a :class:`~instrument.run.runfile.RunSummary`)."""
    recorded = ", ".join(s.recorded) or "nothing per point"
    axes = ", ".join(s.axes) or "no axis moved"
    frames = (f"{s.n_frames} frames of {s.frame_shape[1]}x{s.frame_shape[0]} px"
              if s.frame_shape else "no frames")
    return (f"sample {s.sample_name!r}, {s.n_points} points ({axes}; {recorded}), {frames}; "
            f"plan, bench profile, device identities, policies "
            f"({s.size_bytes / 2**20:.2f} MiB)")
