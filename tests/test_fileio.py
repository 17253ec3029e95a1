"""Atomic writes: readers see the old or the new file, never a partial one."""

import os

import pytest

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
