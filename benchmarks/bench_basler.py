"""The GenICam (Basler) driver on pylon's camera emulation: what one frame costs, and the
copy the driver makes out of the grab buffer.

Per region and pixel format: the median wall time of ``acquire(1)`` (software trigger:
wait for trigger-ready, ``TriggerSoftware``, retrieve, one copy, release), of the same
through the transport alone (the pylon calls and the one copy, without the driver's
bookkeeping: the difference is the driver's own cost), of ``invalidate()`` (stop and
restart of the grab) and of the copy alone (``numpy`` copy of an array of the frame's
size), over ``--frames`` frames. The emulated camera delivers a frame about every 10 ms
whatever its ``AcquisitionFrameRate``, so the first two columns are dominated by it.

    .venv/bin/python benchmarks/bench_basler.py
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from drivers.base import PixelFormat, Roi
from drivers.pylon_transport import open_basler_camera

CASES = (("64x48", Roi(0, 0, 64, 48), PixelFormat.MONO8),
         ("1024x1040", Roi(0, 0, 1024, 1040), PixelFormat.MONO8),
         ("1024x1040", Roi(0, 0, 1024, 1040), PixelFormat.MONO12),
         ("2048x2048", Roi(0, 0, 2048, 2048), PixelFormat.MONO12))


def _median_ms(fn, n: int) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    with open_basler_camera("0815-0000", name="bench", emulation=True) as cam:
        cam.exposure_us = 100.0
        print("| ROI | format | acquire(1) | transport alone | invalidate() | copy alone "
              "| MB/frame |")
        print("|---|---|---|---|---|---|---|")
        t = cam.genicam

        def raw() -> None:
            t.wait_trigger_ready(2.0)
            t.execute("TriggerSoftware")
            t.retrieve(2.0)

        for label, roi, fmt in CASES:
            cam.pixel_format = fmt
            cam.roi = roi
            cam.acquire(3)  # warm up
            acq = _median_ms(lambda: cam.acquire(1), args.frames)
            bare = _median_ms(raw, args.frames)
            inv = _median_ms(cam.invalidate, args.frames)
            sample = np.zeros((roi.height, roi.width), fmt.dtype)
            copy = _median_ms(lambda s=sample: np.array(s, copy=True), args.frames)
            mb = sample.nbytes / 1e6
            print(f"| {label} | {fmt.name} | {acq:.2f} ms | {bare:.2f} ms | {inv:.3f} ms "
                  f"| {copy:.3f} ms | {mb:.2f} |")
        counts = cam.buffer_counts()
        print(f"\nbuffers after the run: {counts}")


if __name__ == "__main__":
    main()
