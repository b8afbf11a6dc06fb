"""Pieces shared by the format readers: errors, checks, streaming text, fans, vertex merging."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from .. import mesh as _mesh_module
from ..errors import MeshReadError

#: File suffixes understood by :func:`~igljoin.io.read_mesh`.
SUPPORTED_SUFFIXES = (".obj", ".off", ".ply", ".stl")
#: File suffixes understood by :func:`~igljoin.io.write_mesh` (VTK through meshio).
WRITE_SUFFIXES = (*SUPPORTED_SUFFIXES, ".vtu", ".vtk")

#: Bytes of a text mesh file parsed at a time; memory held by a text reader
#: is this block plus the arrays parsed so far (bounded by the size guard).
CHUNK_BYTES = 1 << 24
#: A text line longer than this is refused (no mesh record is anywhere near it).
MAX_LINE_BYTES = 1 << 24
#: Any larger vertex index cannot be real (and would overflow int64).
INDEX_LIMIT = 2**62

Arrays = tuple[np.ndarray, np.ndarray, dict, dict]

# Whitespace that Python's str.split() knows in Latin-1 text but bytes.split() does not.
_ODD_SPACE = b"\x0b\x0c\x1c\x1d\x1e\x1f\x85\xa0"


def has_odd_space(data: bytes) -> bool:
    """True if ``data`` holds whitespace other than space, tab, CR and LF."""
    return len(data.translate(None, _ODD_SPACE)) != len(data)


_SPACE = np.zeros(256, dtype=bool)
_SPACE[[9, 10, 13, 32]] = True


def error(path: Path, problem: str, fix: str) -> MeshReadError:
    """Build a :class:`MeshReadError` reading ``"<path>: <problem>; <fix>"``."""
    return MeshReadError(f"{path}: {problem}; {fix}")


def supported(suffixes: tuple = SUPPORTED_SUFFIXES) -> str:
    return ", ".join(suffixes)


def max_elements() -> int:
    """The current size guard (``igljoin.mesh.MAX_ELEMENTS``, which users may change)."""
    return _mesh_module.MAX_ELEMENTS


def guard_error(path: Path, number: int, what: str) -> MeshReadError:
    """The size guard tripped while reading: say where reading stopped."""
    limit = max_elements()
    return error(
        path,
        f"line {number}: more than {limit:,} {what}, the size guard; reading stopped there",
        "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS",
    )


def binary_text_error(path: Path, fmt: str) -> MeshReadError:
    return error(
        path,
        f"contains binary data (NUL bytes) but {fmt} files are plain text",
        f"the file is corrupt or not an {fmt} file; re-export it",
    )


# --------------------------------------------------------------------------- streaming text


def split_lines(data: bytes) -> list[bytes]:
    """Split on ``\\n``, ``\\r\\n`` or ``\\r`` only; a trailing empty piece is dropped.

    :meth:`bytes.splitlines` would also split on ``0x0b``, ``0x0c``, ``0x1c``-``0x1e``.
    """
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    lines = data.split(b"\n")
    if lines and not lines[-1]:
        lines.pop()
    return lines


def line_breaks(data: bytes) -> int:
    """Line breaks in ``data`` (``\\n``, ``\\r\\n`` or ``\\r``), as :func:`split_lines` splits."""
    if b"\r" not in data:  # the common case: one pass
        return data.count(b"\n")
    return data.count(b"\n") + data.count(b"\r") - data.count(b"\r\n")


def _last_break(data: bytes, after: bytes | None) -> int:
    """Index just past the last complete line of ``data`` (0 if it holds none)."""
    if after is not None:
        at = data.rfind(after)
        if at >= 0:
            end = data.find(b"\n", at)
            if end >= 0:
                return end + 1
    return max(data.rfind(b"\n"), data.rfind(b"\r", 0, len(data) - 1)) + 1


class LineTooLong(Exception):
    """Raised by :func:`text_blocks`: a line longer than :data:`MAX_LINE_BYTES` follows the
    blocks yielded so far (the caller, who counts lines, names it: :func:`long_line_error`)."""


def long_line_error(path: Path, fmt: str, number: int) -> MeshReadError:
    return error(
        path,
        f"line {number} is longer than {MAX_LINE_BYTES:,} bytes",
        f"the file is corrupt or not an {fmt} file; re-export it",
    )


def text_blocks(
    path: Path,
    fmt: str,
    *,
    after: bytes | None = None,
    on_binary: Callable[[], MeshReadError] | None = None,
) -> Iterator[bytes]:
    """Read a text mesh file block by block, each block ending at a line break.

    Like :func:`text_chunks` without the line numbers (for a reader that
    counts them itself); a line too long raises :class:`LineTooLong`.
    """
    carry = b""
    with open(path, "rb") as fh:
        while True:
            block = fh.read(CHUNK_BYTES)
            nul = block.find(b"\0")
            if nul >= 0:  # the complete lines before it are still read (and checked) first
                data = carry + block[:nul]
                end = _last_break(data, None)
                if end:
                    yield data[:end]
                raise (on_binary or (lambda: binary_text_error(path, fmt)))()
            data = carry + block if carry else block
            if not block:
                if data:
                    yield data
                return
            end = _last_break(data, after)
            if end == 0:
                if len(data) > MAX_LINE_BYTES:
                    raise LineTooLong
                carry = data
                continue
            chunk, carry = data[:end], data[end:]
            yield chunk


def text_chunks(
    path: Path,
    fmt: str,
    *,
    after: bytes | None = None,
    on_binary: Callable[[], MeshReadError] | None = None,
) -> Iterator[tuple[int, bytes]]:
    """Read a text mesh file block by block, each block ending at a line break.

    Parameters
    ----------
    path : Path
        The file (opened read-only).
    fmt : str
        Format name for messages.
    after : bytes, optional
        Prefer to end blocks on the line holding the last occurrence of this
        keyword (ASCII STL ends them after ``endfacet``).
    on_binary : callable, optional
        Builds the error raised on a NUL byte (default: "contains binary data").

    Yields
    ------
    (int, bytes)
        The 1-based number of the block's first line and the block. Memory
        held is at most :data:`CHUNK_BYTES` plus one unfinished line. At a
        NUL byte the complete lines before it are yielded, then the binary
        error is raised.
    """
    number = 1
    try:
        for chunk in text_blocks(path, fmt, after=after, on_binary=on_binary):
            yield number, chunk
            number += line_breaks(chunk)
    except LineTooLong:
        raise long_line_error(path, fmt, number) from None


def byte_table(chars: bytes) -> np.ndarray:
    """A (256,) bool lookup table, True for the bytes in ``chars``."""
    table = np.zeros(256, dtype=bool)
    table[list(chars)] = True
    return table


#: Bytes of numbers in Python's float syntax (digits, sign, point, exponent, nan/inf/infinity).
FLOAT_BYTES = byte_table(b"0123456789eE+-.nNaAiIfFtTyY \t\n")
#: Bytes of integers.
INT_BYTES = byte_table(b"0123456789- \t\n")


def scan(blob: bytes, allowed: np.ndarray) -> tuple[np.ndarray, int] | None:
    """Tokens per line and the longest token of ``\n``-separated lines of ``blob``.

    Parameters
    ----------
    blob : bytes
        Lines joined by ``\n`` (no trailing newline), tokens separated by
        spaces or tabs.
    allowed : ndarray of bool, shape (256,)
        Bytes that may occur (see :func:`byte_table`).

    Returns
    -------
    (counts, longest) or None
        ``counts`` of shape (lines,), or None if a byte outside ``allowed``
        occurs.
    """
    b = np.frombuffer(blob, dtype=np.uint8)
    if not b.size:
        return np.zeros(0, dtype=np.int64), 0
    if not allowed[b].all():
        return None
    space = _SPACE[b]
    start = ~space
    start[1:] &= space[:-1]
    end = ~space
    end[:-1] &= space[1:]
    starts, ends = np.flatnonzero(start), np.flatnonzero(end)
    longest = int((ends - starts).max()) + 1 if starts.size else 0
    before = np.searchsorted(starts, np.flatnonzero(b == 10))
    return np.diff(before, prepend=0, append=starts.size), longest


def parse_numbers(blob: bytes, dtype, expected: int) -> np.ndarray | None:
    """The whitespace-separated numbers of ``blob``, or None unless exactly ``expected`` parse.

    Callers first restrict the bytes (:func:`scan`) so that numpy's parser
    accepts exactly Python's ``float`` / ``int`` syntax, and integers to at
    most 18 digits (numpy saturates longer ones).
    """
    if expected == 0:
        return np.empty(0, dtype=dtype)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            values = np.fromstring(blob, dtype=dtype, sep=" ")
    except (ValueError, DeprecationWarning):
        return None
    return values if values.size == expected else None


def first_columns(values: np.ndarray, counts: np.ndarray, k: int) -> np.ndarray:
    """The first ``k`` values of each row of a ragged table, shape (rows, k)."""
    if (counts == k).all():
        return values.reshape(-1, k)
    starts = np.cumsum(counts) - counts
    return values[starts[:, None] + np.arange(k)]


# --------------------------------------------------------------------------- geometry


def fan_triangulate(flat: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split polygons into triangle fans around their first vertex.

    Parameters
    ----------
    flat : ndarray of int64, shape (s,)
        Vertex indices of all polygons, concatenated.
    lengths : ndarray of int64, shape (p,)
        Number of vertices of each polygon, all ``>= 3``, summing to ``s``.

    Returns
    -------
    F : ndarray of int64, shape (t, 3)
        Triangles ``(v0, v_k, v_{k+1})`` for ``k = 1 .. len - 2``; triangles keep
        the polygons' order and orientation, ``t = sum(lengths - 2)``.
    owner : ndarray of int64, shape (t,)
        Index of the polygon each triangle comes from.
    """
    if lengths.size and (lengths == 3).all():
        return flat.reshape(-1, 3).astype(np.int64, copy=False), np.arange(lengths.size)
    starts = np.cumsum(lengths) - lengths
    per_poly = lengths - 2
    owner = np.repeat(np.arange(lengths.size), per_poly)
    first_tri = np.cumsum(per_poly) - per_poly
    k = np.arange(owner.size) - first_tri[owner] + 1
    base = starts[owner]
    F = np.stack([flat[base], flat[base + k], flat[base + k + 1]], axis=1)
    return F.astype(np.int64, copy=False), owner


_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def _mix(x: np.ndarray) -> np.ndarray:
    """The splitmix64 finaliser: a well-spread 64-bit hash of each element."""
    x = x ^ (x >> np.uint64(30))
    x = x * _MIX1
    x = x ^ (x >> np.uint64(27))
    x = x * _MIX2
    return x ^ (x >> np.uint64(31))


def merge_vertices(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn a triangle soup into an indexed mesh by merging identical positions.

    Parameters
    ----------
    P : ndarray of float32 or float64, shape (3 t, 3)
        Corner positions, three consecutive rows per triangle.

    Returns
    -------
    V : ndarray of float64, shape (n, 3)
        Distinct positions (equal values; ``-0.0`` equals ``0.0``), in order of
        first appearance.
    F : ndarray of int64, shape (t, 3)
        Triangles indexing ``V``.

    Notes
    -----
    Positions are grouped by sorting a 64-bit hash of their bits; the result
    is then checked for exact equality (every corner equals the vertex it
    was given), and the rare hash collision falls back to
    :func:`numpy.unique` (about three times slower).
    """
    P = np.ascontiguousarray(P + P.dtype.type(0))  # -0.0 + 0.0 == +0.0: one bit pattern
    word = np.uint64 if P.dtype == np.float64 else np.uint32
    K = P.view(word).astype(np.uint64, copy=False)
    h = _mix(_mix(_mix(K[:, 0]) ^ K[:, 1]) ^ K[:, 2])
    order = np.argsort(h)  # not stable (faster): each group's first index is found below
    hs = h[order]
    new = np.empty(order.size, dtype=bool)
    new[:1] = True
    np.not_equal(hs[1:], hs[:-1], out=new[1:])
    group = np.cumsum(new) - 1
    first = np.minimum.reduceat(order, np.flatnonzero(new)) if order.size else order
    by_first = np.argsort(first)  # distinct: any sort gives one order
    rank = np.empty(first.size, dtype=np.int64)
    rank[by_first] = np.arange(first.size)
    F = np.empty(P.shape[0], dtype=np.int64)
    F[order] = rank[group]
    kept = first[by_first]  # the row of P that each vertex comes from
    # np.take along axis 0 gathers rows much faster than fancy indexing
    if not (np.take(np.take(K, kept, axis=0), F, axis=0) == K).all():  # a hash collision
        _, kept, inverse = np.unique(P, axis=0, return_index=True, return_inverse=True)
        by_first = np.argsort(kept)
        rank = np.empty(kept.size, dtype=np.int64)
        rank[by_first] = np.arange(kept.size)
        F, kept = rank[inverse.reshape(-1)], kept[by_first]
    V = np.take(P, kept, axis=0).astype(np.float64, copy=False)
    return V, F.reshape(-1, 3)


def attribute_name(raw: str) -> str:
    """Map a file's property name to a valid attribute name (an identifier)."""
    if raw.isidentifier():
        return raw
    cleaned = "".join(c if (c.isascii() and c.isalnum()) else "_" for c in raw)
    return cleaned if cleaned.isidentifier() else f"p_{cleaned}"
