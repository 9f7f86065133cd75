"""Frames compressed outside HDF5 (instrument.run.frame_chunks): the chunks are HDF5's own
shuffle + deflate bytes, so any HDF5 reader reads the run file as before."""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from instrument.run.frame_chunks import deflate_level, encode_chunk, encode_frames
from instrument.run.storage import FrameData, PointRecord, RunHeader, RunStore

DTYPES = [np.uint8, np.uint16, np.int16, np.uint32, np.float32, np.float64]


def _frames_ds(f: h5py.File, name: str, shape: tuple[int, ...], dtype, **filters):
    return f.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape),
                            chunks=(1, *shape), dtype=dtype, **filters)


def _hdf5_chunk(tmp_path, frame: np.ndarray, level: int) -> bytes:
    """The chunk HDF5's own filters store for ``frame``."""
    with h5py.File(tmp_path / "ref.h5", "w") as f:
        ds = _frames_ds(f, "x", frame.shape, frame.dtype, compression="gzip",
                        compression_opts=level, shuffle=True)
        ds.resize(1, axis=0)
        ds[0] = frame
        f.flush()
        return bytes(ds.id.read_direct_chunk((0, *(0,) * frame.ndim))[1])


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frame=st.sampled_from(DTYPES).flatmap(
           lambda dt: hnp.arrays(dt, hnp.array_shapes(min_dims=2, max_dims=2, max_side=40))),
       level=st.integers(1, 9))
def test_chunk_is_hdf5s_shuffle_and_deflate_byte_for_byte(tmp_path, frame, level):
    assert encode_chunk(frame, level) == _hdf5_chunk(tmp_path, frame, level)


def test_a_sensor_frame_and_a_non_contiguous_view(tmp_path):
    rng = np.random.default_rng(7)
    frame = (100 + rng.poisson(3.0, (256, 320))).astype(np.uint16)
    assert encode_chunk(frame, 1) == _hdf5_chunk(tmp_path, frame, 1)
    view = np.asfortranarray(frame)[:, ::2]  # neither C-contiguous nor whole
    assert encode_chunk(view, 1) == _hdf5_chunk(tmp_path, np.ascontiguousarray(view), 1)


def test_only_shuffle_then_deflate_datasets_of_one_frame_a_chunk(tmp_path):
    with h5py.File(tmp_path / "p.h5", "w") as f:
        ok = _frames_ds(f, "ok", (8, 8), np.uint16, compression="gzip",
                        compression_opts=4, shuffle=True)
        assert deflate_level(ok) == 4
        plain = _frames_ds(f, "plain", (8, 8), np.uint16)
        no_shuffle = _frames_ds(f, "ns", (8, 8), np.uint16, compression="gzip")
        crc = _frames_ds(f, "crc", (8, 8), np.uint16, compression="gzip", shuffle=True,
                         fletcher32=True)
        lzf = _frames_ds(f, "lzf", (8, 8), np.uint16, compression="lzf", shuffle=True)
        two = f.create_dataset("two", shape=(0, 8, 8), maxshape=(None, 8, 8),
                               chunks=(2, 8, 8), dtype=np.uint16, compression="gzip",
                               shuffle=True)
        for ds in (plain, no_shuffle, crc, lzf, two):
            assert deflate_level(ds) is None
        frame = np.zeros((8, 8), np.uint16)
        assert encode_frames([frame], plain) is None
        # a frame h5py would convert or reject is left to h5py
        assert encode_frames([frame.astype(np.uint8)], ok) is None
        assert encode_frames([frame.astype(">u2")], ok) is None
        assert encode_frames([np.zeros((8, 9), np.uint16)], ok) is None
        assert encode_frames([], ok) is None
        assert encode_frames([frame, frame + 1], ok) == [encode_chunk(frame, 4),
                                                       encode_chunk(frame + 1, 4)]


def _header(n: int) -> RunHeader:
    return RunHeader(
        run_id="r1", plan_kind="brdf_in_plane", plan_name="p", plan_text="[plan]",
        profile_text="[bench]", bench_name="b", sample_name="s", sample_description="",
        axes=("sample_theta",), planned_targets=[[float(i)] for i in range(n)],
        planned_angles=[[float(i), 0, float(i), 180] for i in range(n)],
        planned_label=["sample"] * n, planned_light=[True] * n,
        planned_exposure_us=[float("nan")] * n, acquisition_policy="{}",
        retry_policies="{}", identities={}, device_kinds={}, geometry={"kind": "in_plane"},
        calibration={}, software_version="test", created=time.time())


@pytest.mark.parametrize("n_frames", [1, 5])
def test_run_store_writes_hdf5s_chunks_and_reads_back_the_frames(tmp_path, n_frames):
    rng = np.random.default_rng(3)
    points = [[(64 + rng.poisson(2.0 + 50 * k, (48, 64))).astype(np.uint16)
               for k in range(n_frames)] for _ in range(3)]
    store = RunStore.create(tmp_path / "r.h5", _header(3), fsync=False)
    for i, frames in enumerate(points):
        store.append(PointRecord(i, "sample", 0.0, 0.0, (float(i),), frames=[
            FrameData(fr, 100.0, True, 0.0, 0.0) for fr in frames]))
    store.close("finished")
    flat = [fr for frames in points for fr in frames]
    with h5py.File(tmp_path / "r.h5") as f:
        ds = f["entry/data/frames"]
        assert (ds.compression, ds.compression_opts, ds.shuffle) == ("gzip", 1, True)
        assert np.array_equal(ds[:], np.stack(flat))
        for k, fr in enumerate(flat):
            mask, chunk = ds.id.read_direct_chunk((k, 0, 0))
            assert mask == 0
            assert bytes(chunk) == _hdf5_chunk(tmp_path, fr, 1)
