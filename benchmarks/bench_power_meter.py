"""PM100USB queries per second through the emulated USB path.

Every operation goes the whole way a real one does, minus the wire: the driver formats
SCPI, :mod:`drivers.usbtmc` frames USBTMC transfers and calls pyusb, pyusb's
``usb.core.Device`` dispatches to the backend, and :mod:`hw_mocks.usb.backend` checks the
framing and runs the SCPI firmware with its noise model. The figures are therefore the
host-side cost of the stack (Python, pyusb, framing), an upper bound on what the driver
could sustain; a real PM100USB adds its USB latency (≥ 1 ms per full-speed transfer
pair) and its measurement time.

Cases:

- ``read_power_w``: ``PM100USB.read_power_w()`` = ``MEAS:POW?`` (one DEV_DEP_MSG_OUT,
  one REQUEST_DEV_DEP_MSG_IN, one bulk-IN read), parsed to watts;
- ``usbtmc query``: the same ``MEAS:POW?`` through :class:`UsbtmcDevice` alone;
- ``averaging = n``: a setting followed by the ``SYST:ERR?`` check (two round trips);
- ``read_power_w, 8-byte packets``: ``MEAS:POW?`` with wMaxPacketSize 8, so the reply
  takes several packets.

Usage::

    python benchmarks/bench_power_meter.py            # 3 s per case
    python benchmarks/bench_power_meter.py --quick    # 0.5 s per case
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import usb

from drivers.thorlabs_pm100 import PM100USB
from drivers.usbtmc import UsbtmcDevice
from hw_mocks import registry
from hw_mocks.usb import backend_from_url, get_firmware


def run_case(operation: Callable[[], object], seconds: float) -> dict[str, float]:
    for _ in range(20):   # warm caches (pyusb endpoint lookup, regexes)
        operation()
    latencies: list[float] = []
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        t0 = time.perf_counter()
        operation()
        latencies.append(time.perf_counter() - t0)
    elapsed = time.perf_counter() - start
    latencies.sort()
    return {
        "ops_per_s": len(latencies) / elapsed,
        "median_us": statistics.median(latencies) * 1e6,
        "p99_us": latencies[int(0.99 * (len(latencies) - 1))] * 1e6,
        "n": float(len(latencies)),
    }


def open_meter(url: str) -> PM100USB:
    registry.reset()
    backend = backend_from_url(url)
    name = registry.parse_url(url)[1]
    get_firmware(name).optical_power_w = lambda _wl: 1.0e-3
    return PM100USB(name="power_meter", backend=backend, timeout_s=1.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.5 s per case")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per case")
    args = parser.parse_args(argv)
    seconds = args.seconds if args.seconds is not None else (0.5 if args.quick else 3.0)

    print(f"python {platform.python_version()}, pyusb {usb.__version__}, "
          f"{platform.machine()}, {seconds:g} s per case")
    print(f"{'case':34s} {'ops/s':>9s} {'median µs':>10s} {'p99 µs':>9s} {'n':>7s}")
    results: dict[str, dict[str, float]] = {}

    meter = open_meter("simusb://power_meter?serial=P2000000")
    results["read_power_w (MEAS:POW?)"] = run_case(meter.read_power_w, seconds)
    counts = iter(range(10**9))
    results["averaging = n (+SYST:ERR?)"] = run_case(
        lambda: setattr(meter, "averaging", 1 + next(counts) % 100), seconds)
    meter.close()

    registry.reset()
    tmc = UsbtmcDevice(vendor_id=0x1313, product_id=0x8072,
                       backend=backend_from_url("simusb://raw?serial=P2000000"), timeout_s=1.0)
    results["usbtmc query MEAS:POW?"] = run_case(lambda: tmc.query("MEAS:POW?"), seconds)
    tmc.close()

    meter = open_meter("simusb://small?serial=P2000000&packet=8")
    results["read_power_w, 8-byte packets"] = run_case(meter.read_power_w, seconds)
    meter.close()
    registry.reset()

    for case, r in results.items():
        print(f"{case:34s} {r['ops_per_s']:9.0f} {r['median_us']:10.0f} "
              f"{r['p99_us']:9.0f} {int(r['n']):7d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
