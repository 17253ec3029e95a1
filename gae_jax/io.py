"""Crash-safe file writing: write to a temporary file in the same folder, then rename."""

from __future__ import annotations

import os
import tempfile

READABLE_FILE_MODE = 0o644


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Writes `data` to `path` so that readers see either the old file or the whole new one."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=os.path.basename(path))
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        # mkstemp creates the file private (0600); results are meant to be shared like any file.
        os.chmod(tmp, READABLE_FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
