"""A small real tmpfs, for tests of what a full disk does."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest


@contextlib.contextmanager
def small_tmpfs(kib: int) -> Iterator[Path]:
    """Mount a ``kib``-KiB tmpfs; writes beyond that fail with ENOSPC like a full disk.

    Skips the calling test where mounting is not allowed (not root, no ``mount``).
    """
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root")
    mnt = Path("/tmp") / f"igljoin-full-{uuid.uuid4().hex[:8]}"
    mnt.mkdir()
    ok = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(mnt)], capture_output=True
    )
    if ok.returncode != 0:
        mnt.rmdir()
        pytest.skip(f"cannot mount a tmpfs here: {ok.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)
        mnt.rmdir()
