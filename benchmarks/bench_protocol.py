"""Command round trips per second through the real drivers, on emulated controllers.

For each driver (Newport SMC100 ``Smc100Axis``, Thorlabs APT ``AptMotor`` with a K10CR1,
Zaber ``ZaberAxis`` with message ids, without and with checksums) and each transport (the
in-process pyserial URL link, and a real pseudo-terminal served by
:class:`hw_mocks.pty_server.PtyServer`), this times

- ``position``: one position query (SMC100 ``TP``; APT ``MOT_REQ_POSCOUNTER``; Zaber
  ``get pos``), i.e. one request/reply round trip through the driver's full stack
  (formatting, stale-input discard, framing, decoding, typed errors);
- ``status()``: the driver's full status snapshot (SMC100: ``TS`` then ``TP``, two round
  trips; APT: K10CR1 status bits then position counter, two round trips; KDC101 one DC
  status-update request; Zaber: ``get pos`` then ``warnings``, two round trips).

Reported per case: operations per second, median and 99th-percentile latency. Timings
are measurements for comparison, not pass/fail gates.

Usage::

    python benchmarks/bench_protocol.py            # 3 s per case
    python benchmarks/bench_protocol.py --quick    # 0.5 s per case
    python benchmarks/bench_protocol.py --only Zaber
"""

from __future__ import annotations

import argparse
import contextlib
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.base import MotionAxis
from drivers.newport_smc100 import Smc100Axis
from drivers.thorlabs_apt import AptMotor
from drivers.transport import add_url_handler_package
from drivers.zaber_ascii import ZaberAxis
from hw_mocks.clock import ScaledClock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.firmware.smc100 import Smc100Emulator
from hw_mocks.firmware.zaber import ZaberEmulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.urlhandler.protocol_simapt import make_emulator as make_apt_emulator

SPEED = 100.0


@contextlib.contextmanager
def serve(transport: str, url: str, emulator: Callable[[], FirmwareEmulator],
          open_axis: Callable[[str], MotionAxis]) -> Iterator[MotionAxis]:
    """``open_axis(url)`` in-process, or ``open_axis(path)`` of ``emulator()`` on a pty."""
    with contextlib.ExitStack() as stack:
        port = url if transport == "url" else stack.enter_context(PtyServer(emulator())).path
        axis = open_axis(port)
        stack.callback(axis.close)
        yield axis


def smc100(transport: str, name: str):
    return serve(transport, f"simsmc://{name}?speed={SPEED:g}",
                 lambda: Smc100Emulator(name, clock=ScaledClock(SPEED)),
                 lambda port: Smc100Axis(port, name=name))


def apt(transport: str, name: str):
    options = {"model": "K10CR1", "speed": f"{SPEED:g}"}
    return serve(transport, f"simapt://{name}?model=K10CR1&speed={SPEED:g}",
                 lambda: make_apt_emulator(name, options),
                 lambda port: AptMotor(port, name=name, stage="K10CR1", rts_settle_s=0.0,
                                       flush_s=0.0))


def zaber(*, checksum: bool):
    def opener(transport: str, name: str):
        return serve(transport, f"simzaber://{name}?speed={SPEED:g}",
                     lambda: ZaberEmulator(name, clock=ScaledClock(SPEED)),
                     lambda port: ZaberAxis(port, name=name, microstep_size=0.000234375,
                                            flush_s=0.0, checksum=checksum))
    return opener


def time_op(op: Callable[[], object], seconds: float) -> dict[str, float]:
    for _ in range(20):  # warm-up
        op()
    latencies = []
    end = time.perf_counter() + seconds
    while True:
        t0 = time.perf_counter()
        op()
        t1 = time.perf_counter()
        latencies.append(t1 - t0)
        if t1 >= end:
            break
    latencies.sort()
    return {
        "n": len(latencies),
        "per_s": len(latencies) / sum(latencies),
        "median_us": statistics.median(latencies) * 1e6,
        "p99_us": latencies[min(len(latencies) - 1, int(0.99 * len(latencies)))] * 1e6,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.5 s per case")
    parser.add_argument("--seconds", type=float, default=3.0, help="time per case")
    parser.add_argument("--only", default="", help="run the drivers whose label starts so")
    args = parser.parse_args(argv)
    seconds = 0.5 if args.quick else args.seconds
    add_url_handler_package("hw_mocks.urlhandler")

    drivers: list[tuple[str, Callable]] = [
        ("SMC100", smc100), ("APT K10CR1", apt), ("Zaber", zaber(checksum=False)),
        ("Zaber+csum", zaber(checksum=True))]
    drivers = [(label, opener) for label, opener in drivers if label.startswith(args.only)]

    print(f"python {platform.python_version()} on {platform.machine()}, "
          f"{seconds:g} s per case")
    header = f"{'driver':<11} {'transport':<9} {'operation':<10} {'ops/s':>8} " \
             f"{'median µs':>10} {'p99 µs':>9} {'n':>7}"
    print(header)
    print("-" * len(header))
    for label, opener in drivers:
        for transport in ("url", "pty"):
            tag = label.lower().replace(" ", "_").replace("+", "_")
            with opener(transport, f"bench_{tag}_{transport}") as axis:
                for op_name, op in (("position", lambda a=axis: a.position),
                                    ("status()", axis.status)):
                    r = time_op(op, seconds)
                    print(f"{label:<11} {transport:<9} {op_name:<10} {r['per_s']:>8.0f} "
                          f"{r['median_us']:>10.0f} {r['p99_us']:>9.0f} {r['n']:>7d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
