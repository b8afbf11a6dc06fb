"""OBJ reading: ``v`` and ``f`` records (everything else is ignored) and writing.

Each block of the file is parsed with vectorised numpy when its records are
plainly written (``v x y z ...`` / ``f a b c ...`` at the start of a line, no
comments or continuations inside them); any other block goes through the
record-by-record parser below, which is the reference for every check and
message (with line numbers). Both give identical results.
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
    byte_table,
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

_CORNER_BYTES = byte_table(b"0123456789-/ \t\n")
_AFTER_SLASH = re.compile(rb"/\S*")
_BLANK = np.zeros(256, dtype=bool)
_BLANK[[9, 32]] = True


class _State:
    """What has been read so far (vertices, polygons) and an unfinished continuation."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.n_vertices = 0
        self.flat: list[np.ndarray] = []
        self.lengths: list[np.ndarray] = []
        self.face_lines: list[np.ndarray] = []
        self.n_triangles = 0
        self.pending: list[str] = []
        self.pending_start = 0


# --------------------------------------------------------------------------- reference parser


def _vertex(path: Path, number: int, tokens: list[str]) -> tuple[float, float, float]:
    if len(tokens) < 4:
        raise error(
            path,
            f"line {number}: vertex record has {len(tokens) - 1} coordinates, needs 3",
            "write vertices as 'v x y z'",
        )
    try:
        return float(tokens[1]), float(tokens[2]), float(tokens[3])
    except ValueError:
        raise error(
            path,
            f"line {number}: vertex coordinates {' '.join(tokens[1:4])!r} are not numbers",
            "the file is corrupt; re-export it",
        ) from None


def _face(path: Path, number: int, tokens: list[str], n_seen: int) -> list[int]:
    """Parse ``f`` corners (``a``, ``a/b``, ``a//c``, ``a/b/c``) to 0-based indices."""
    if len(tokens) < 4:
        raise error(
            path,
            f"line {number}: face has {len(tokens) - 1} vertices; a face needs at least 3",
            "remove degenerate faces or re-export the mesh",
        )
    out = []
    for corner in tokens[1:]:
        try:
            i = int(corner.split("/", 1)[0])
        except ValueError:
            raise error(
                path,
                f"line {number}: face corner {corner!r} is not a vertex index",
                "write faces as 'f a b c' with 1-based integer indices",
            ) from None
        if i == 0:
            raise error(
                path,
                f"line {number}: face uses vertex index 0, but OBJ indices start at 1",
                "re-export the mesh with 1-based indices",
            )
        if i > INDEX_LIMIT:
            raise error(
                path,
                f"line {number}: face references vertex {i}, far beyond any vertex count",
                "the file is corrupt; re-export it",
            )
        if i < 0 and n_seen + i < 0:
            raise error(
                path,
                f"line {number}: relative index {i} points before the first vertex "
                f"({n_seen} vertices are defined above it)",
                "the file is truncated or corrupt; re-export it",
            )
        out.append(i - 1 if i > 0 else n_seen + i)
    return out


def _records(state: _State, first: int, data: bytes):
    """Yield ``(line_number, tokens)`` of non-empty records, joining ``\\`` continuations."""
    for offset, raw in enumerate(split_lines(data)):
        number = first + offset
        line = raw.decode("latin-1").split("#", 1)[0].rstrip()
        if not state.pending:
            state.pending_start = number
        if line.endswith("\\"):
            state.pending.append(line[:-1])
            continue
        tokens = " ".join([*state.pending, line]).split()
        state.pending = []
        if tokens:
            yield state.pending_start, tokens


def _flush(state: _State):
    """The record left unfinished by a continuation on the last line, if any."""
    tokens = " ".join(state.pending).split()
    state.pending = []
    if tokens:
        yield state.pending_start, tokens


def _slow(path: Path, state: _State, records) -> None:
    limit = max_elements()
    verts: list[tuple[float, float, float]] = []
    flat: list[int] = []
    lengths: list[int] = []
    lines: list[int] = []
    for number, tokens in records:
        if tokens[0] == "v":
            if state.n_vertices + len(verts) >= limit:
                raise guard_error(path, number, "vertices")
            verts.append(_vertex(path, number, tokens))
        elif tokens[0] == "f":
            corners = _face(path, number, tokens, state.n_vertices + len(verts))
            state.n_triangles += len(corners) - 2
            if state.n_triangles > limit:
                raise guard_error(path, number, "triangles")
            flat.extend(corners)
            lengths.append(len(corners))
            lines.append(number)
    state.vertices.append(np.array(verts, dtype=np.float64).reshape(-1, 3))
    state.n_vertices += len(verts)
    state.flat.append(np.array(flat, dtype=np.int64))
    state.lengths.append(np.array(lengths, dtype=np.int64))
    state.face_lines.append(np.array(lines, dtype=np.int64))


# --------------------------------------------------------------------------- vectorised parser


def _blob(lines: list[bytes], rows: np.ndarray, key: bytes) -> bytes | None:
    """The records ``rows`` joined by newlines with their one-letter key blanked out."""
    blob = b"\n".join([lines[i] for i in rows.tolist()])
    if b"#" in blob or blob.count(key) != rows.size:
        return None
    return blob.replace(key, b" ")


def _fast(state: _State, first: int, data: bytes) -> bool:
    """Parse a block of plain records; False (nothing changed) if it needs the reference parser."""
    if state.pending or b"\\" in data or has_odd_space(data):
        return False
    lines = split_lines(data)
    kinds = np.array(lines, dtype="S2")
    head = kinds.view(np.uint8).reshape(-1, 2)
    letter = (head[:, 0] == ord("v")) | (head[:, 0] == ord("f"))
    second = head[:, 1]
    if (_BLANK[head[:, 0]] | (letter & ((second == 0) | (second == 9)))).any():
        return False  # indented or tab-separated records: leave them to the reference
    is_v = kinds == b"v "
    v_rows = np.flatnonzero(is_v)
    f_rows = np.flatnonzero(kinds == b"f ")
    limit = max_elements()
    if state.n_vertices + v_rows.size > limit:
        return False  # the reference parser stops at the exact line
    vblob = _blob(lines, v_rows, b"v")
    fblob = _blob(lines, f_rows, b"f")
    if vblob is None or fblob is None:
        return False
    v_scan, f_scan = scan(vblob, FLOAT_BYTES), scan(fblob, _CORNER_BYTES)
    if v_scan is None or f_scan is None:
        return False
    (v_counts, _), (f_counts, longest) = v_scan, f_scan
    if (v_counts < 3).any() or (f_counts < 3).any():
        return False
    if state.n_triangles + int((f_counts - 2).sum()) > limit:
        return False
    if b"/" in fblob:
        fblob = _AFTER_SLASH.sub(b"", fblob)
        f_scan = scan(fblob, INT_BYTES)
        if f_scan is None or f_scan[0].sum() != f_counts.sum():
            return False  # a corner such as '/2' has no vertex index
        longest = f_scan[1]
    if longest > 18:
        return False  # numpy would saturate; the reference reports the index
    values = parse_numbers(vblob, np.float64, int(v_counts.sum()))
    corners = parse_numbers(fblob, np.int64, int(f_counts.sum()))
    if values is None or corners is None or (corners == 0).any():
        return False
    seen = state.n_vertices + np.cumsum(is_v)[f_rows]
    index = np.where(corners > 0, corners - 1, np.repeat(seen, f_counts) + corners)
    if (index < 0).any():
        return False
    state.vertices.append(first_columns(values, v_counts, 3))
    state.n_vertices += v_rows.size
    state.flat.append(index)
    state.lengths.append(f_counts.astype(np.int64))
    state.face_lines.append(first + f_rows)
    state.n_triangles += int((f_counts - 2).sum())
    return True


def read(path: Path) -> Arrays:
    """Read ``v`` and ``f`` records of an OBJ file (all other records are ignored)."""
    state = _State()
    for first, data in text_chunks(path, "OBJ"):
        if not _fast(state, first, data):
            _slow(path, state, _records(state, first, data))
    _slow(path, state, _flush(state))
    lengths = np.concatenate(state.lengths)
    if state.n_vertices == 0 and lengths.size == 0:
        raise error(
            path,
            "contains no OBJ vertex ('v') or face ('f') records",
            "check that it is really an OBJ mesh file",
        )
    V = np.concatenate(state.vertices)
    flat = np.concatenate(state.flat)
    if flat.size and flat.max() >= V.shape[0]:
        bad = int(np.flatnonzero(flat >= V.shape[0])[0])
        poly = int(np.searchsorted(np.cumsum(lengths), bad, side="right"))
        line = int(np.concatenate(state.face_lines)[poly])
        raise error(
            path,
            f"line {line}: face references vertex {int(flat[bad]) + 1} but the "
            f"file defines only {V.shape[0]} vertices",
            "the file is truncated or corrupt; re-export it",
        )
    F, _ = fan_triangulate(flat, lengths)
    return V, F, {}, {}


def write(tmp: Path, mesh: Mesh) -> None:
    """Text OBJ with ``%.17g`` coordinates (exact float64 round trip)."""
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"# written by igljoin: {mesh.n_vertices} vertices, {mesh.n_faces} faces\n")
        np.savetxt(fh, mesh.V, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, mesh.F + 1, fmt="f %d %d %d")
