"""Atomic writes: readers see the old or the new file, never a partial one; .npz files that
`np.load` reads back exactly."""

import os

import numpy as np
import pytest

from gae_jax.util import fileio
from gae_jax.util.fileio import atomic_write_bytes


def test_atomic_write_replaces_and_leaves_no_temporaries(tmp_path):
    path = tmp_path / "sub" / "file.bin"
    atomic_write_bytes(str(path), b"old")
    atomic_write_bytes(str(path), b"new")
    assert path.read_bytes() == b"new"
    assert os.listdir(path.parent) == ["file.bin"]
    assert (path.stat().st_mode & 0o777) == 0o644


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "file.bin"
    atomic_write_bytes(str(path), b"old")
    with pytest.raises(TypeError):
        atomic_write_bytes(str(path), object())  # not bytes: fails mid-write
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["file.bin"]


@pytest.mark.parametrize("compressed", [False, True])
def test_npz_round_trips_every_dtype_through_np_load(tmp_path, compressed):
    rng = np.random.default_rng(0)
    arrays = dict(images=rng.integers(0, 255, (3, 8, 8, 3), dtype=np.uint8),
                  depth=rng.normal(size=(3, 8, 8)).astype(np.float64),
                  labels=np.full((4, 4), -1, np.int8), hit=np.eye(4, dtype=bool),
                  names=np.array(["lips", "skin"]), scalar=np.float32(2.5))
    path = str(tmp_path / "arrays.npz")
    fileio.write_npz(path, arrays, compressed=compressed)
    with np.load(path) as loaded:
        assert sorted(loaded.files) == sorted(arrays)
        for name, array in arrays.items():
            assert loaded[name].dtype == np.asarray(array).dtype
            np.testing.assert_array_equal(loaded[name], array)


def test_a_compressed_npz_is_smaller_on_repetitive_arrays():
    arrays = dict(background=np.ones((64, 64, 3), np.float32))
    assert len(fileio.npz_bytes(arrays, compressed=True)) * 20 < len(fileio.npz_bytes(arrays))
