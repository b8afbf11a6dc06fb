"""STL reading (binary and ASCII) and writing.

Binary STL is read with one :func:`numpy.fromfile` after its size is checked
against the triangle count of its header. ASCII STL is streamed block by
block: blocks of plainly written facets are parsed by the compiled parser of
:mod:`igljoin.io._decimal` (large blocks) or with vectorised numpy, others by
the line-by-line reference parser below (every check and message). The
compiled parser runs on up to :data:`THREADS` blocks at once, read ahead of
the block being taken (so up to ``THREADS + 1`` blocks are held); results are
taken, and blocks handed back to the other parsers, in file order, so every
message and line number is the one a sequential read gives. Corners with
equal coordinates are merged into one vertex.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshReadError
from ..mesh import Mesh
from ._common import (
    FLOAT_BYTES,
    Arrays,
    LineTooLong,
    error,
    guard_error,
    has_odd_space,
    line_breaks,
    long_line_error,
    max_elements,
    merge_vertices,
    parse_numbers,
    split_lines,
    text_blocks,
)

RECORD = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
HEADER_BYTES = 80
_FLOAT32_MAX = float(np.finfo(np.float32).max)
# A plain ASCII facet is 21 tokens: facet normal a b c outer loop
# vertex x y z vertex x y z vertex x y z endloop endfacet
_FACET = {0: b"facet", 1: b"normal", 5: b"outer", 6: b"loop", 7: b"vertex", 11: b"vertex"}
_FACET |= {15: b"vertex", 19: b"endloop", 20: b"endfacet"}
_COORDS = (8, 9, 10, 12, 13, 14, 16, 17, 18)
#: Blocks of facets at least this long are parsed by the compiled parser
#: (:mod:`igljoin.io._decimal`; importing numba costs more than it saves on small files).
COMPILED_BYTES = 1 << 21
#: Threads parsing such blocks at once (the file is still read, and checked, in order;
#: each started thread is joined before the reader returns).
THREADS = min(4, os.cpu_count() or 1)


class _State:
    def __init__(self) -> None:
        self.corners: list[np.ndarray] = []
        self.n_corners = 0
        self.in_loop = False
        self.loop_size = 0
        self.loop_line = 0
        self.closed = False
        #: Line breaks of the block just read, if the compiled parser counted them.
        self.counted: int | None = None


# --------------------------------------------------------------------------- binary


def _declared(path: Path, size: int) -> int:
    with open(path, "rb") as fh:
        fh.seek(HEADER_BYTES)
        return int(np.frombuffer(fh.read(4), dtype="<u4")[0])


def _read_binary(path: Path, count: int) -> np.ndarray:
    if count > max_elements():
        raise error(
            path,
            f"binary STL header declares {count:,} triangles, more than the size guard of "
            f"{max_elements():,}",
            "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS",
        )
    with open(path, "rb") as fh:
        fh.seek(HEADER_BYTES + 4)
        records = np.fromfile(fh, dtype=RECORD, count=count)
    return records["vertices"].reshape(-1, 3)


# --------------------------------------------------------------------------- ASCII reference


def _slow(path: Path, state: _State, first: int, data: bytes) -> None:
    corners: list[tuple[float, float, float]] = []
    limit = 3 * max_elements()
    for offset, raw in enumerate(split_lines(data)):
        text = raw.decode("latin-1")
        tokens = text.split()
        if not tokens:
            continue
        number = first + offset
        key = tokens[0].lower()
        if key == "vertex":
            if not state.in_loop:
                raise error(
                    path,
                    f"line {number}: 'vertex' outside a facet's 'outer loop'",
                    "the file is corrupt; re-export it",
                )
            try:
                corners.append((float(tokens[1]), float(tokens[2]), float(tokens[3])))
            except (ValueError, IndexError):
                raise error(
                    path,
                    f"line {number}: {text.strip()[:50]!r} is not 'vertex x y z'",
                    "the file is truncated or corrupt; re-export it",
                ) from None
            state.loop_size += 1
            if state.n_corners + len(corners) > limit:
                raise guard_error(path, number, "triangles")
        elif key == "outer":
            if state.in_loop:
                raise error(
                    path,
                    f"line {number}: 'outer loop' before the facet begun on line "
                    f"{state.loop_line} has its 'endloop'",
                    "the file is truncated or corrupt; re-export it",
                )
            state.in_loop, state.loop_size, state.loop_line = True, 0, number
        elif key == "endloop":
            if state.loop_size != 3:
                raise error(
                    path,
                    f"line {number}: facet has {state.loop_size} vertices; STL facets are "
                    "triangles",
                    "re-export the mesh as triangles",
                )
            state.in_loop, state.loop_size = False, 0
        elif key == "endsolid":
            state.closed = True
    state.corners.append(np.array(corners, dtype=np.float64).reshape(-1, 3))
    state.n_corners += len(corners)


def _span(data: bytes) -> tuple[int, int] | None:
    """The lines of ``data`` from its first ``facet`` to its last ``endfacet``, or None."""
    start = data.find(b"facet")
    stop = data.rfind(b"endfacet")
    if start < 0 or stop < 0:
        return None
    start = data.rfind(b"\n", 0, start) + 1
    stop = data.find(b"\n", stop)
    return start, len(data) if stop < 0 else stop + 1


def _compiled_job(data: bytes) -> Callable[[], tuple[int, int, tuple | None]] | None:
    """The compiled parse of a block's facets, to run on any thread, or None if not tried.

    The job returns ``(start, stop, parsed)``: the span it parsed and the result of
    :func:`igljoin.io._decimal.parse_facets` (None: not plain facets).
    """
    span = _span(data)
    if span is None or span[1] - span[0] < COMPILED_BYTES or b"vertex" in data[: span[0]]:
        return None
    from . import _decimal  # numba: imported on first use

    start, stop = span
    return lambda: (start, stop, _decimal.parse_facets(data, start, stop))


def _compiled(path: Path, state: _State, first: int, data: bytes, job) -> bool:
    """Take the compiled parse of a block (``job``: a future or a callable), or return False."""
    start, stop, parsed = job.result() if isinstance(job, Future) else job()
    if parsed is None:
        return False
    corners, lines = parsed
    if state.n_corners + corners.shape[0] > 3 * max_elements():
        return False
    head, tail = data[:start], data[stop:]
    _slow(path, state, first, head)
    state.corners.append(corners)
    state.n_corners += corners.shape[0]
    head_lines = line_breaks(head)
    _slow(path, state, first + head_lines + lines, tail)
    state.counted = head_lines + lines + line_breaks(tail)
    return True


def _fast(path: Path, state: _State, first: int, data: bytes, job=None) -> bool:
    """Parse the plain facets of a block (its head and tail lines go to the reference).

    ``job`` is the block's compiled parse (:func:`_compiled_job`), if any.
    """
    if state.in_loop:
        return False
    if job is not None and _compiled(path, state, first, data, job):
        return True
    span = _span(data)
    if span is None:
        return False
    start, stop = span
    if has_odd_space(data):
        return False
    head, body, tail = data[:start], data[start:stop], data[stop:]
    if b"vertex" in head or b"\r" in body:
        return False
    tokens = body.split()
    facets, rest = divmod(len(tokens), 21)
    if rest or any(tokens[j::21].count(word) != facets for j, word in _FACET.items()):
        return False
    if state.n_corners + 3 * facets > 3 * max_elements():
        return False
    blobs = [b" ".join(tokens[j::21]) for j in _COORDS]
    if any(not FLOAT_BYTES[np.frombuffer(blob, dtype=np.uint8)].all() for blob in blobs):
        return False
    coords = [parse_numbers(blob, np.float64, facets) for blob in blobs]
    if any(c is None for c in coords):
        return False
    _slow(path, state, first, head)
    state.corners.append(np.stack(coords, axis=1).reshape(-1, 3))
    state.n_corners += 3 * facets
    _slow(path, state, first + head.count(b"\n") + body.count(b"\n"), tail)
    return True


def _ahead(blocks: Iterator[bytes], pool: list) -> Iterator[tuple[bytes | None, object]]:
    """The blocks with their compiled parses started ahead on up to :data:`THREADS` threads.

    Yields ``(block, job)`` in file order (``job`` a future, or a callable when one thread
    is used, or None); an error met while reading ahead is yielded as ``(None, error)``
    once the blocks before it are done, so that every message comes in file order.
    ``pool`` receives the thread pool once one is started (the caller shuts it down).
    """
    waiting: deque = deque()
    try:
        for data in blocks:
            job = _compiled_job(data)
            if job is not None and THREADS > 1:
                if not pool:
                    pool.append(ThreadPoolExecutor(THREADS, thread_name_prefix="igljoin-stl"))
                job = pool[0].submit(job)
            waiting.append((data, job))
            while len(waiting) > THREADS:
                yield waiting.popleft()
    except (MeshReadError, LineTooLong) as exc:
        waiting.append((None, exc))
    while waiting:
        yield waiting.popleft()


def _read_ascii(path: Path, size: int) -> np.ndarray:
    state = _State()

    def on_binary() -> Exception:
        return _truncated_binary(path, size) if size >= HEADER_BYTES + 4 else _too_short(path, size)

    blocks = text_blocks(path, "STL", after=b"endfacet", on_binary=on_binary)
    number = 1  # of the block's first line
    pool: list[ThreadPoolExecutor] = []
    try:
        for data, job in _ahead(blocks, pool):
            if data is None:
                if isinstance(job, LineTooLong):
                    raise long_line_error(path, "STL", number) from None
                raise job
            state.counted = None
            if not _fast(path, state, number, data, job):
                _slow(path, state, number, data)
            number += line_breaks(data) if state.counted is None else state.counted
    finally:
        if pool:
            pool[0].shutdown(wait=True, cancel_futures=True)
    if state.in_loop or not state.closed:
        raise error(
            path,
            "ASCII STL ends before 'endsolid'; the file is truncated",
            "re-export or re-download the file",
        )
    return np.concatenate(state.corners)


def _truncated_binary(path: Path, size: int):
    declared = _declared(path, size)
    need = HEADER_BYTES + 4 + declared * RECORD.itemsize
    return error(
        path,
        f"binary STL header declares {declared} triangles ({need} bytes) but the file has "
        f"{size} bytes; it is truncated or not an STL file",
        "re-export or re-download the file",
    )


def _too_short(path: Path, size: int):
    return error(
        path,
        f"is only {size} bytes, too short for a binary STL, and is not ASCII STL",
        "check that it is really an STL file",
    )


def read(path: Path) -> Arrays:
    """Read binary or ASCII STL and merge identical corner positions into vertices."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        start = fh.read(1024)
    count = _declared(path, size) if size >= HEADER_BYTES + 4 else None
    if count is not None and HEADER_BYTES + 4 + count * RECORD.itemsize == size:
        P = _read_binary(path, count)
    elif start.lstrip()[:5].lower() == b"solid" and b"\0" not in start:
        P = _read_ascii(path, size)
    elif count is not None:
        raise _truncated_binary(path, size)
    else:
        raise _too_short(path, size)
    if P.shape[0] == 0:
        return np.empty((0, 3)), np.empty((0, 3), dtype=np.int64), {}, {}
    V, F = merge_vertices(P)
    return V, F, {}, {}


# --------------------------------------------------------------------------- writing


def _face_normals(corners: np.ndarray) -> np.ndarray:
    """Unit normals (m, 3) of triangles given as corners (m, 3, 3); zero if degenerate."""
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def check_binary_range(target: Path, mesh: Mesh) -> None:
    """Refuse coordinates that float32 (binary STL) cannot hold."""
    peak = float(np.abs(mesh.V).max())
    if peak > _FLOAT32_MAX:
        raise MeshError(
            f"cannot write {target}: coordinates reach {peak:.3g}, beyond the float32 range "
            f"of binary STL ({_FLOAT32_MAX:.3g}); write ASCII STL (binary=False) or PLY, or "
            "rescale the mesh"
        )


def write(tmp: Path, mesh: Mesh, binary: bool) -> None:
    """Binary STL (float32 coordinates) or ASCII STL (``%.17g``, exact)."""
    corners = mesh.V[mesh.F]
    with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: zero normals
        normals = _face_normals(corners)
    normals[~np.isfinite(normals).all(axis=1)] = 0.0
    if binary:
        records = np.zeros(mesh.n_faces, dtype=RECORD)
        records["normal"] = normals
        records["vertices"] = corners
        with open(tmp, "wb") as fh:
            fh.write(b"binary STL written by igljoin".ljust(HEADER_BYTES, b" "))
            fh.write(np.array([mesh.n_faces], dtype="<u4").tobytes())
            fh.write(records.tobytes())
        return
    facet = (
        "facet normal %.17g %.17g %.17g\n  outer loop\n"
        + "    vertex %.17g %.17g %.17g\n" * 3
        + "  endloop\nendfacet"
    )
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write("solid igljoin\n")
        np.savetxt(fh, np.hstack([normals, corners.reshape(-1, 9)]), fmt=facet)
        fh.write("endsolid igljoin\n")
