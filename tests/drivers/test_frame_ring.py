"""FrameRing: the bounded stream buffer, its dropped-frame count and its stale-frame epochs."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from drivers.base import Frame, FrameRing, Roi


def frame(index: int) -> Frame:
    return Frame(data=np.zeros((2, 2), np.uint16), index=index, timestamp=float(index),
                 exposure_us=1.0, gain=0.0, saturation_dn=4095.0, bit_depth=12,
                 roi=Roi(0, 0, 2, 2))


def test_overflow_drops_the_oldest_and_counts_each_drop():
    ring = FrameRing(4)
    for i in range(10):
        assert ring.put(frame(i))
    assert len(ring) == 4 and ring.dropped == 6
    assert [ring.get(0.0).index for _ in range(4)] == [6, 7, 8, 9]
    assert ring.get(0.0) is None and ring.dropped == 6


def test_clear_discards_without_counting_and_rejects_frames_of_the_old_epoch():
    ring = FrameRing(3)
    epoch = ring.epoch
    ring.put(frame(0), epoch=epoch)
    ring.put(frame(1), epoch=epoch)
    assert ring.clear() == 2
    assert ring.dropped == 0 and ring.epoch == epoch + 1
    # A frame whose exposure began before the clear arrives late: it is not kept.
    assert not ring.put(frame(2), epoch=epoch)
    assert len(ring) == 0 and ring.dropped == 0
    assert ring.put(frame(3), epoch=ring.epoch)
    assert ring.get(0.0).index == 3


def test_get_waits_for_a_producer_and_times_out_otherwise():
    ring = FrameRing(2)
    start = time.monotonic()
    assert ring.get(0.05) is None
    assert time.monotonic() - start >= 0.04  # it did wait
    timer = threading.Timer(0.05, ring.put, args=(frame(7),))
    timer.start()
    got = ring.get(5.0)
    timer.join()
    assert got is not None and got.index == 7


def test_capacity_must_be_positive():
    with pytest.raises(ValueError):
        FrameRing(0)
