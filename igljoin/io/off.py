"""OFF reading (ASCII OFF and its COFF/NOFF/... variants) and writing.

Blocks of plain vertex and face lines are parsed with vectorised numpy; the
header, and any block with comments or unusual values, go through the
record-by-record parser, the reference for every check and message.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..mesh import Mesh
from ._common import (
    FLOAT_BYTES,
    INDEX_LIMIT,
    INT_BYTES,
    Arrays,
    error,
    fan_triangulate,
    first_columns,
    guard_error,
    has_odd_space,
    max_elements,
    parse_numbers,
    scan,
    split_lines,
    text_chunks,
)

_LINE = re.compile(rb"[^\r\n]*(?:\r\n|\r|\n)?")
# Shortest records: "x y z\n" is 6 bytes, "3 a b c\n" 8 bytes.
_MIN_VERTEX_BYTES, _MIN_FACE_BYTES = 6, 8


class _State:
    def __init__(self) -> None:
        self.stage = "keyword"  # then "counts", "data"
        self.n_v = self.n_f = 0
        self.records = 0  # data records seen
        self.counts_line = 0
        self.vertices: list[np.ndarray] = []
        self.flat: list[np.ndarray] = []
        self.lengths: list[np.ndarray] = []
        self.n_triangles = 0

    @property
    def vertices_left(self) -> int:
        return max(self.n_v - self.records, 0)

    @property
    def faces_left(self) -> int:
        return max(self.n_v + self.n_f - max(self.records, self.n_v), 0)


# --------------------------------------------------------------------------- header


def _keyword(path: Path, state: _State, tokens: list[str]) -> list[str]:
    keyword = tokens[0] if tokens else ""
    prefix = keyword[:-3]
    if not keyword.endswith("OFF") or set(prefix) - set("STCN"):
        raise error(
            path,
            f"does not start with the 'OFF' keyword (found {keyword[:20]!r})",
            "check that it is really an OFF mesh file",
        )
    rest = tokens[1:]
    if rest and rest[0].upper() == "BINARY":
        raise error(path, "is a binary OFF file, which is not supported", "save it as text OFF")
    return rest


def _counts(path: Path, state: _State, number: int, rest: list[str]) -> None:
    try:
        n_v, n_f = int(rest[0]), int(rest[1])
    except (ValueError, IndexError):
        raise error(
            path,
            f"line {number}: expected vertex and face counts, found {' '.join(rest)[:40]!r}",
            "the header must be 'OFF' then 'n_vertices n_faces n_edges'",
        ) from None
    if n_v < 0 or n_f < 0:
        raise error(path, f"declares negative counts ({n_v}, {n_f})", "the file is corrupt")
    limit = max_elements()
    for count, what in ((n_v, "vertices"), (n_f, "faces")):
        if count > limit:
            raise error(
                path,
                f"header declares {count:,} {what}, more than the size guard of {limit:,}",
                "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS",
            )
    need, size = n_v * _MIN_VERTEX_BYTES + n_f * _MIN_FACE_BYTES, path.stat().st_size
    if need > size:
        raise error(
            path,
            f"declares {n_v} vertices and {n_f} faces, which take at least {need} bytes, but "
            f"the file has only {size} bytes; the file is truncated",
            "re-export or re-download the file",
        )
    state.n_v, state.n_f, state.counts_line, state.stage = n_v, n_f, number, "data"


# --------------------------------------------------------------------------- reference parser


def _vertex(path: Path, number: int, tokens: list[str]) -> list[float]:
    try:
        row = [float(t) for t in tokens[:3]]
    except ValueError:
        row = []
    if len(row) != 3:
        raise error(
            path,
            f"line {number}: vertex {' '.join(tokens[:3])!r} is not three numbers",
            "the file is truncated or corrupt; re-export it",
        )
    return row


def _face(path: Path, number: int, tokens: list[str]) -> list[int]:
    try:
        k = int(tokens[0])
        corners = [int(t) for t in tokens[1 : 1 + k]]
    except ValueError:
        raise error(
            path,
            f"line {number}: face {' '.join(tokens)[:40]!r} is not a list of integers",
            "faces must read 'k i_1 ... i_k'; the file is corrupt",
        ) from None
    if k < 3 or len(corners) != k:
        raise error(
            path,
            f"line {number}: face declares {k} vertices and lists {len(corners)}; "
            "a face needs at least 3",
            "the file is truncated or corrupt; re-export it",
        )
    far = [i for i in corners if abs(i) > INDEX_LIMIT]
    if far:
        raise error(
            path,
            f"line {number}: face references vertex {far[0]}, far beyond any vertex count",
            "the file is corrupt; re-export it",
        )
    return corners


def _slow(path: Path, state: _State, first: int, data: bytes) -> None:
    verts: list[list[float]] = []
    flat: list[int] = []
    lengths: list[int] = []
    limit = max_elements()
    for offset, raw in enumerate(split_lines(data)):
        tokens = raw.decode("latin-1").split("#", 1)[0].split()
        if not tokens:
            continue
        number = first + offset
        if state.stage == "keyword":
            rest = _keyword(path, state, tokens)
            state.stage = "counts"
            if rest:
                _counts(path, state, number, rest)
        elif state.stage == "counts":
            _counts(path, state, number, tokens)
        elif state.records < state.n_v:
            verts.append(_vertex(path, number, tokens))
            state.records += 1
        elif state.records < state.n_v + state.n_f:
            corners = _face(path, number, tokens)
            state.n_triangles += len(corners) - 2
            if state.n_triangles > limit:
                raise guard_error(path, number, "triangles")
            flat.extend(corners)
            lengths.append(len(corners))
            state.records += 1
    state.vertices.append(np.array(verts, dtype=np.float64).reshape(-1, 3))
    state.flat.append(np.array(flat, dtype=np.int64))
    state.lengths.append(np.array(lengths, dtype=np.int64))


# --------------------------------------------------------------------------- vectorised parser


def _fast(state: _State, data: bytes) -> bool:
    """Parse a block of plain data lines; False (nothing changed) if it needs the reference."""
    if state.stage != "data" or b"#" in data or has_odd_space(data):
        return False
    records = [line for line in split_lines(data) if line and not line.isspace()]
    n_vertex = min(state.vertices_left, len(records))
    n_face = min(state.faces_left, len(records) - n_vertex)
    vblob = b"\n".join(records[:n_vertex])
    fblob = b"\n".join(records[n_vertex : n_vertex + n_face])
    v_scan, f_scan = scan(vblob, FLOAT_BYTES), scan(fblob, INT_BYTES)
    if v_scan is None or f_scan is None or f_scan[1] > 18:
        return False  # other bytes, or integers numpy would saturate
    v_counts, f_counts = v_scan[0], f_scan[0]
    if (v_counts < 3).any():
        return False
    values = parse_numbers(vblob, np.float64, int(v_counts.sum()))
    numbers = parse_numbers(fblob, np.int64, int(f_counts.sum()))
    if values is None or numbers is None:
        return False
    starts = np.cumsum(f_counts) - f_counts
    k = numbers[starts]
    if (k < 3).any() or (f_counts < k + 1).any():
        return False
    if state.n_triangles + int((k - 2).sum()) > max_elements():
        return False
    if (f_counts == 4).all():
        flat = numbers.reshape(-1, 4)[:, 1:].reshape(-1)
    else:
        begin = np.repeat(starts + 1 - (np.cumsum(k) - k), k)
        flat = numbers[begin + np.arange(int(k.sum()))]
    state.vertices.append(first_columns(values, v_counts, 3))
    state.flat.append(flat)
    state.lengths.append(k.astype(np.int64))
    state.n_triangles += int((k - 2).sum())
    state.records += n_vertex + n_face
    return True


def _header(path: Path, state: _State, first: int, data: bytes) -> tuple[int, bytes]:
    """Feed lines to the reference parser until the header is read; return the rest."""
    pos = 0
    while state.stage != "data" and pos < len(data):
        end = _LINE.match(data, pos).end()
        line = data[pos:end]
        _slow(path, state, first, line)
        first += line.endswith((b"\n", b"\r"))
        pos = end
    return first, data[pos:]


def read(path: Path) -> Arrays:
    """Read an ASCII OFF file (also COFF/NOFF/...: extra per-vertex values are ignored)."""
    state = _State()
    for first, data in text_chunks(path, "OFF"):
        if state.stage != "data":
            first, data = _header(path, state, first, data)
        if data and not _fast(state, data):
            _slow(path, state, first, data)
    if state.stage == "keyword":
        _keyword(path, state, [])
    if state.stage == "counts":
        raise error(path, "ends after the 'OFF' keyword", "the file is truncated; re-export")
    if state.records < state.n_v + state.n_f:
        raise error(
            path,
            f"declares {state.n_v} vertices and {state.n_f} faces but only {state.records} data "
            "lines follow; the file is truncated",
            "re-export or re-download the file",
        )
    V = np.concatenate(state.vertices)
    if state.n_f == 0:
        return V, np.empty((0, 3), dtype=np.int64), {}, {}
    F, _ = fan_triangulate(np.concatenate(state.flat), np.concatenate(state.lengths))
    return V, F, {}, {}


def write(tmp: Path, mesh: Mesh) -> None:
    """Text OFF with ``%.17g`` coordinates (exact float64 round trip)."""
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"OFF\n{mesh.n_vertices} {mesh.n_faces} 0\n")
        np.savetxt(fh, mesh.V, fmt="%.17g %.17g %.17g")
        np.savetxt(fh, mesh.F, fmt="3 %d %d %d")
