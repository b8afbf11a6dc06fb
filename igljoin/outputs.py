"""Output folders igljoin may write into without harming what else is there.

The policy (``docs/pipelines.md``, "Output folders"):

* igljoin writes its own files into a folder beside whatever is already
  there, each file atomically, and never deletes or replaces a file it did
  not write;
* what it wrote is listed, with a SHA-256 per file taken at write time, in the
  folder's manifest ``.igljoin-manifest.json``. Only files named there may be
  replaced (or removed, when a rerun of a case no longer produces them);
* an existing file (not a folder) given as an output folder is refused, and
  so is a folder entry of the same name as one of igljoin's outputs that the
  manifest does not list.

Files are first written into a staging folder beside the target folder
(``.NAME.tmp-XXXXXXXX``, marked by an empty ``.igljoin-staging`` file so that
a later batch removes only staging folders igljoin made) and then moved into
place by :func:`publish`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import shutil
from collections.abc import Iterable
from pathlib import Path

from .atomic import atomic_write_text, fsync_dir
from .errors import OutputError

__all__ = [
    "MANIFEST",
    "STAGING_MARK",
    "check_folder",
    "file_sha256",
    "make_staging",
    "publish",
    "read_manifest",
    "remove_stale_staging",
]

#: Name of the manifest igljoin keeps in every folder it writes into.
MANIFEST = ".igljoin-manifest.json"
#: Empty file that marks a staging folder as igljoin's.
STAGING_MARK = ".igljoin-staging"

_STAGING_DIR = re.compile(r"^\..+\.(tmp|new)-[0-9a-f]{8}$")
_MANIFEST_TMP = re.compile(r"^\.\.igljoin-manifest\.tmp-[0-9a-f]{8}\.json$")
_MAX_MANIFEST_BYTES = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_manifest(folder: str | os.PathLike) -> dict[str, str | None]:
    """The files igljoin wrote into ``folder``: ``{name: sha256}`` (empty if none).

    A manifest that is missing, not a regular file, too large, not JSON, or
    not of the form igljoin writes counts as no manifest: nothing in the
    folder is then igljoin's to replace.

    Parameters
    ----------
    folder : str or os.PathLike

    Returns
    -------
    dict of str to str or None
        File name -> SHA-256 recorded at write time (``None`` for a name
        claimed before its file was written).
    """
    path = Path(folder) / MANIFEST
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > _MAX_MANIFEST_BYTES:
            return {}
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return {}
    files = doc.get("files") if isinstance(doc, dict) else None
    if doc.get("written_by") != "igljoin" or not isinstance(files, dict):
        return {}
    return {
        str(k): v
        for k, v in files.items()
        if isinstance(k, str) and "/" not in k and (v is None or isinstance(v, str))
    }


def _write_manifest(folder: Path, files: dict[str, str | None]) -> None:
    doc = {"written_by": "igljoin", "files": dict(sorted(files.items()))}
    atomic_write_text(folder / MANIFEST, json.dumps(doc, indent=2, sort_keys=True) + "\n")


def check_folder(folder: str | os.PathLike, names: Iterable[str], *, what: str = "output") -> None:
    """Refuse to write ``names`` into ``folder`` if that would replace a foreign entry.

    Parameters
    ----------
    folder : str or os.PathLike
        The target folder (it need not exist yet).
    names : iterable of str
        The file names igljoin is about to write there.
    what : str
        How to call the folder in messages (e.g. ``"OUT"``).

    Raises
    ------
    OutputError
        If ``folder`` is an existing file, or one of ``names`` exists in it and
        is not listed in its manifest (or is a folder or a symbolic link).
    """
    folder = Path(folder)
    if folder.is_symlink() and not folder.exists():
        raise OutputError(
            f"{what} {folder} is a broken symbolic link; remove it or choose another folder"
        )
    if folder.exists() and not folder.is_dir():
        raise OutputError(
            f"{what} {folder} is an existing file, not a folder; igljoin writes a folder of "
            "outputs there and never replaces a file it did not write: choose a folder path"
        )
    if not folder.is_dir():
        return
    owned = read_manifest(folder)
    for name in sorted(set(names)):
        entry = folder / name
        if not (entry.exists() or entry.is_symlink()):
            continue
        if entry.is_symlink() or not entry.is_file():
            raise OutputError(
                f"{what} {folder} already holds a folder, link or special file (e.g. a FIFO) "
                f"named {name!r}, which igljoin writes as a regular file and never replaces: "
                "move it away or choose another output folder"
            )
        if name not in owned:
            raise OutputError(
                f"{what} {folder} already holds {name!r}, which igljoin did not write (it is "
                f"not in {MANIFEST}); igljoin never replaces files it did not write: move it "
                "away or choose another output folder"
            )


def make_staging(final: str | os.PathLike) -> Path:
    """Create a marked staging folder beside ``final`` (``.NAME.tmp-XXXXXXXX``).

    Parameters
    ----------
    final : str or os.PathLike
        The folder the staged files are meant for; its parent must exist.

    Returns
    -------
    pathlib.Path
    """
    final = Path(final)
    for _ in range(100):
        token = secrets.token_hex(4)
        tmp = final.with_name(f".{final.name}.tmp-{token}")
        # made under another name and renamed once marked, so that no folder of
        # the staging name ever lacks the mark (a kill between the two steps
        # leaves a marked ".new-" folder, which remove_stale_staging also removes)
        new = final.with_name(f".{final.name}.new-{token}")
        if os.path.lexists(tmp):
            continue
        try:
            new.mkdir()
        except FileExistsError:
            continue
        (new / STAGING_MARK).touch()
        try:
            os.rename(new, tmp)
        except OSError:
            shutil.rmtree(new, ignore_errors=True)
            if tmp.exists():
                continue
            raise
        return tmp
    raise FileExistsError(f"cannot create a temporary folder beside {final}")


def publish(staging: Path, final: Path, *, exclusive: bool) -> dict[str, str]:
    """Move the files of ``staging`` into ``final`` and record them in its manifest.

    Parameters
    ----------
    staging : pathlib.Path
        From :func:`make_staging`; removed at the end.
    final : pathlib.Path
        The output folder (created if missing).
    exclusive : bool
        ``True`` (a case folder): igljoin's files in ``final`` become exactly
        the staged ones; files of an earlier run that this run did not write
        are removed, but only those the manifest lists. ``False`` (a batch
        folder): the staged files are added to or replace igljoin's files;
        nothing else is touched.

    Returns
    -------
    dict of str to str
        The new manifest, ``{name: sha256}``.

    Raises
    ------
    OutputError
        See :func:`check_folder` (checked before anything is moved).

    Notes
    -----
    Order, so that a kill at any moment leaves every name igljoin wrote in the
    manifest (hence replaceable by the next run) and every output it lists
    either the old or the new complete file: (1) check, (2) manifest extended
    with the new names, (3) files moved in with :func:`os.replace`, (4) files
    of the earlier run no longer produced removed, (5) final manifest.
    """
    names = sorted(p.name for p in staging.iterdir() if p.name != STAGING_MARK)
    check_folder(final, names)
    hashes = {}
    for name in names:
        f = staging / name
        fd = os.open(f, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        hashes[name] = file_sha256(f)
    created = not final.exists()
    final.mkdir(parents=True, exist_ok=True)
    owned = read_manifest(final)
    try:
        _write_manifest(final, {**owned, **dict.fromkeys(names)})
    except OSError:
        if created:  # leave no empty folder of ours behind (e.g. on a full disk)
            with contextlib.suppress(OSError):
                final.rmdir()
        raise
    for name in names:
        os.replace(staging / name, final / name)
    fsync_dir(final)
    if exclusive:
        new = dict(hashes)
        for name in set(owned) - set(names):
            entry = final / name
            if entry.is_file() and not entry.is_symlink():
                entry.unlink()
    else:
        new = {k: v for k, v in owned.items() if (final / k).is_file()}
        new.update(hashes)
    _write_manifest(final, new)
    shutil.rmtree(staging, ignore_errors=True)
    return new


def remove_stale_staging(folder: Path) -> list[Path]:
    """Remove what a killed run of igljoin left in ``folder``; return what was removed.

    Only staging folders that carry igljoin's mark and temporary files of
    igljoin's own manifest are removed; anything else, even with a similar
    name, is left alone.
    """
    removed = []
    for p in folder.iterdir():
        if p.is_symlink():
            continue
        if p.is_dir() and _STAGING_DIR.match(p.name) and (p / STAGING_MARK).is_file():
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
        elif p.is_file() and _MANIFEST_TMP.match(p.name):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed
