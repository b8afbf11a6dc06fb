"""Atomic file output: a file is either fully written or not touched at all.

Writers write to a hidden temporary file next to the target; only when they
finish without error is the temporary file flushed to disk and renamed onto
the target with :func:`os.replace` (atomic on POSIX file systems). On any
error the temporary file is removed and the previous target, if any, is left
exactly as it was.
"""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]

#: ``errno`` values that mean "no space left" (full disk or exhausted quota).
_DISK_FULL = frozenset(
    code for code in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if code is not None
)

_CREATE_ATTEMPTS = 100


def _check_target(target: Path) -> None:
    """Refuse targets whose directory is missing or that are directories."""
    parent = target.parent
    if not parent.exists():
        raise FileNotFoundError(
            errno.ENOENT,
            f"cannot write {target}: its directory {parent} does not exist; "
            "create the directory first",
            str(parent),
        )
    if not parent.is_dir():
        raise NotADirectoryError(
            errno.ENOTDIR,
            f"cannot write {target}: {parent} is not a directory",
            str(parent),
        )
    if target.is_dir():
        raise IsADirectoryError(
            errno.EISDIR,
            f"cannot write {target}: it is an existing directory; choose a file name",
            str(target),
        )


def _create_temp(target: Path) -> Path:
    """Create an empty hidden temporary file beside ``target`` and return its path.

    The name is ``.<stem>.tmp-<random><suffix>``: hidden, unique, and ending in
    the target's own suffix so that writers that choose a format from the
    suffix still work. The file is created exclusively (never reusing an
    existing file) with the default permissions of the process umask.
    """
    for _ in range(_CREATE_ATTEMPTS):
        tmp = target.with_name(f".{target.stem}.tmp-{secrets.token_hex(4)}{target.suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(
        errno.EEXIST, f"cannot create a temporary file beside {target}", str(target.parent)
    )


def _fsync_file(path: Path) -> None:
    """Flush the contents of ``path`` to stable storage."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(directory: Path) -> None:
    """Best-effort flush of a directory entry (a rename) to stable storage."""
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
    try:
        fd = os.open(directory, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _copy_mode(source: Path, tmp: Path) -> None:
    """Give ``tmp`` the permission bits of an existing ``source`` (if any)."""
    try:
        mode = source.stat().st_mode
    except OSError:
        return
    os.chmod(tmp, mode & 0o7777)


def _remove_quietly(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _disk_full_error(exc: OSError, target: Path) -> OSError:
    """The clear error raised instead of a raw ENOSPC/EDQUOT ``OSError``."""
    return OSError(
        exc.errno,
        f"the disk is full (or the quota is exhausted) while writing {target}; "
        "no partial file was left and any previous file is unchanged; "
        "free some space and write again",
        str(target),
    )


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; on success it atomically becomes ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The final file. Its directory must exist.

    Yields
    ------
    pathlib.Path
        A hidden, already-created empty file in the same directory as ``path``,
        named ``.<stem>.tmp-<random><suffix>`` (same suffix as ``path``). Write
        the whole output to it, e.g. by opening it with mode ``"wb"``.

    Raises
    ------
    FileNotFoundError
        If the directory of ``path`` does not exist (it is not created).
    IsADirectoryError
        If ``path`` is an existing directory.
    OSError
        If the disk is full (``ENOSPC``) or the quota is exhausted (``EDQUOT``),
        re-raised with a message that says so, names ``path`` and states that no
        partial file was left. Other errors propagate unchanged.

    Notes
    -----
    On normal exit of the ``with`` block the temporary file is fsynced and
    renamed onto ``path`` with :func:`os.replace`, then the directory is
    fsynced. If ``path`` already exists its permission bits are kept. If the
    block raises, the temporary file is deleted, ``path`` is left untouched
    and the exception is re-raised.

    Examples
    --------
    >>> with atomic_path("out.txt") as tmp:  # doctest: +SKIP
    ...     tmp.write_text("hello")
    """
    target = Path(path)
    _check_target(target)
    tmp = _create_temp(target)
    try:
        yield tmp
        _copy_mode(target, tmp)
        _fsync_file(tmp)
        os.replace(tmp, target)
    except BaseException as exc:
        _remove_quietly(tmp)
        if isinstance(exc, OSError) and exc.errno in _DISK_FULL:
            raise _disk_full_error(exc, target) from exc
        raise
    fsync_dir(target.parent)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`).

    Parameters
    ----------
    path : str or os.PathLike
        The final file; its directory must exist.
    data : bytes-like
        The complete new contents.

    Returns
    -------
    pathlib.Path
        ``path`` as a :class:`~pathlib.Path`.
    """
    target = Path(path)
    with atomic_path(target) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return target


def atomic_write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`).

    Parameters
    ----------
    path : str or os.PathLike
        The final file; its directory must exist.
    text : str
        The complete new contents, written without newline translation.
    encoding : str, optional
        Text encoding, UTF-8 by default.

    Returns
    -------
    pathlib.Path
        ``path`` as a :class:`~pathlib.Path`.
    """
    target = Path(path)
    with atomic_path(target) as tmp, open(tmp, "w", encoding=encoding, newline="") as fh:
        fh.write(text)
    return target
