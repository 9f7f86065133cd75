"""A point's frames compressed outside HDF5, to the bytes HDF5's own filters would store.

Why: h5py holds the GIL while HDF5 runs a dataset's filters, so ``ds[i] = frame`` on a
shuffle + gzip dataset compressed one frame at a time (~20 ms for a 1024² MONO12 frame
on the dev box) and stopped every other thread of the process meanwhile. The engine
waits for a point's commit before it acquires the next one (ADR 0010), so that time was
spent with the other cores idle. :func:`zlib.compress` releases the GIL; the frames of a
point are compressed in parallel here and written with ``write_direct_chunk``.

The bytes are HDF5's (ADR 0115):

* shuffle (HDF5's ``H5Z_FILTER_SHUFFLE``, H5Zshuffle.c): the n-byte elements of a chunk
  rewritten as n planes, plane k holding byte k of every element — for a C-contiguous
  array, the transpose of its ``(elements, n)`` byte view; a no-op for 1-byte elements;
* deflate (``H5Z_FILTER_DEFLATE``, H5Zdeflate.c): zlib's ``compress2`` at the dataset's
  level, i.e. a zlib stream with the default window and memory level, which is what
  :func:`zlib.compress` makes.

A chunk is written with filter mask 0 (both filters applied), so every HDF5 reader decodes
it as before; ``tests/instrument/run/test_frame_chunks.py`` compares the chunks with
HDF5's, byte for byte. A dataset with any other filter pipeline is written through h5py.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np

__all__ = ["deflate_level", "encode_chunk", "encode_frames"]

#: Threads that compress a point's frames: the box's cores, a few at most (each holds a
#: shuffled copy of one frame).
MAX_THREADS = 4


def deflate_level(ds: h5py.Dataset) -> int | None:
    """The deflate level of ``ds`` if its chunks are one frame each and its filters are
    exactly shuffle then deflate (what :mod:`instrument.run.storage` creates); else None."""
    if ds.chunks is None or ds.chunks != (1, *ds.shape[1:]):
        return None
    plist = ds.id.get_create_plist()
    filters = [plist.get_filter(i) for i in range(plist.get_nfilters())]
    if [f[0] for f in filters] != [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE]:
        return None
    level = filters[1][2]
    return int(level[0]) if len(level) == 1 else None  # a level HDF5 would not state


def encode_chunk(frame: np.ndarray, level: int) -> bytes:
    """One frame as HDF5 stores it after shuffle and deflate at ``level`` (module
    docstring); ``frame`` must have the dataset's dtype, in native byte order."""
    raw = np.ascontiguousarray(frame)
    if raw.itemsize > 1:
        raw = raw.view(np.uint8).reshape(-1, raw.itemsize).T
    # zlib reads the (C-contiguous) array's buffer directly: no bytes copy of the frame
    return zlib.compress(np.ascontiguousarray(raw).data, level)


def encode_frames(frames: Sequence[np.ndarray], ds: h5py.Dataset) -> list[bytes] | None:
    """The chunks of ``frames`` for ``ds``, compressed on parallel threads; None where
    ``ds`` is not a shuffle + deflate dataset of one frame a chunk or a frame does not
    match its dtype and shape exactly (then h5py writes them)."""
    level = deflate_level(ds)
    if level is None or not frames:
        return None
    if any(f.dtype != ds.dtype or not f.dtype.isnative or f.shape != ds.shape[1:]
           for f in frames):
        return None
    threads = min(len(frames), _usable_cores(), MAX_THREADS)
    if threads <= 1:
        return [encode_chunk(f, level) for f in frames]
    # a pool per point (a few threads, ~0.1 ms to start) rather than one kept across
    # points: nothing to shut down, and nothing stale in a process forked from this one
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="run-deflate") as pool:
        return list(pool.map(encode_chunk, frames, [level] * len(frames)))


def _usable_cores() -> int:
    """The cores this process may run on (its affinity where the OS tells it: a
    container's or ``taskset``'s share, not the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS has no affinity call
        return os.cpu_count() or 1
