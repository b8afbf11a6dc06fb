"""Reading and writing triangle meshes: OBJ, OFF, PLY and STL.

Formats are chosen from the file suffix (case-insensitive).

* PLY is read and written with :mod:`plyfile` (ASCII and binary, any mix of
  property types). Extra scalar vertex and face properties become
  :attr:`Mesh.vertex_attributes` / :attr:`Mesh.face_attributes`.
* OBJ, OFF and STL are parsed by the small numpy-based readers below.
  libigl's ``read_triangle_mesh`` is deliberately not used: it aborts the
  process on some PLY files and, on malformed OBJ/OFF/STL input, silently
  returns nonsense (out-of-range or ``-1`` face indices, millions of garbage
  faces from a corrupt polygon size, an empty mesh for a directory) instead
  of an error.

Every malformed input raises :class:`~igljoin.errors.MeshReadError` whose
message names the file, the problem and the fix; a missing file raises
:class:`FileNotFoundError`. Input files are only ever opened read-only.
Output goes through :func:`~igljoin.atomic.atomic_path`, so a failed write
never leaves a partial file.
"""

from __future__ import annotations

import errno
import os
import stat
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import plyfile

from .atomic import atomic_path
from .errors import MeshError, MeshReadError
from .mesh import Mesh, as_mesh

__all__ = ["read_mesh", "write_mesh", "SUPPORTED_SUFFIXES"]

#: File suffixes understood by :func:`read_mesh` and :func:`write_mesh`.
SUPPORTED_SUFFIXES = (".obj", ".off", ".ply", ".stl")

_FACE_LIST_NAMES = ("vertex_indices", "vertex_index")
_INT32 = np.iinfo(np.int32)
_PLY_HEADER_SCAN = 1 << 20  # bytes read to find the PLY header (headers are far smaller)
_INDEX_LIMIT = 2**62  # any larger OBJ index cannot be real (and would overflow int64)
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
_STL_HEADER_BYTES = 80
_Arrays = tuple[np.ndarray, np.ndarray, dict, dict]


# --------------------------------------------------------------------------- helpers


def _error(path: Path, problem: str, fix: str) -> MeshReadError:
    """Build a :class:`MeshReadError` reading ``"<path>: <problem>; <fix>"``."""
    return MeshReadError(f"{path}: {problem}; {fix}")


def _supported() -> str:
    return ", ".join(SUPPORTED_SUFFIXES)


def _check_input_file(path: Path) -> None:
    """Raise unless ``path`` is an existing, non-empty regular file."""
    try:
        st = path.stat()
    except FileNotFoundError:
        where = "" if path.is_absolute() else f" (relative to {Path.cwd()})"
        raise FileNotFoundError(
            errno.ENOENT,
            f"mesh file not found: {path}{where}; check the path and its spelling",
            str(path),
        ) from None
    if stat.S_ISDIR(st.st_mode):
        raise _error(
            path, "is a directory, not a mesh file", f"pass a file ending in {_supported()}"
        )
    if not stat.S_ISREG(st.st_mode):
        raise _error(path, "is not a regular file", "pass a mesh file saved on disk")
    if st.st_size == 0:
        raise _error(path, "is empty (0 bytes)", "re-export the mesh; the file holds no data")


def _format_of(path: Path) -> str:
    """Return the lower-case suffix of ``path`` or raise for an unknown one."""
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        shown = repr(path.suffix) if path.suffix else "no suffix"
        raise _error(
            path,
            f"has {shown}, which is not a supported mesh format",
            f"use one of the supported suffixes {_supported()} (convert the file first)",
        )
    return suffix


def _read_text(path: Path, fmt: str) -> str:
    """Read a text mesh file; refuse binary content (NUL bytes).

    Bytes are decoded as Latin-1, which never fails: the syntax of OBJ and OFF
    is ASCII, and comments or material names may hold any byte.
    """
    with open(path, "rb") as fh:
        data = fh.read()
    if b"\0" in data:
        raise _error(
            path,
            f"contains binary data (NUL bytes) but {fmt} files are plain text",
            f"the file is corrupt or not an {fmt} file; re-export it",
        )
    return data.decode("latin-1")


def _lines(text: str) -> list[str]:
    """Split text on ``\\n``, ``\\r\\n`` or ``\\r`` only.

    :meth:`str.splitlines` would also split on bytes such as ``0x85`` or
    ``0x0c`` that may appear inside comments of Latin-1 decoded files.
    """
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _fan_triangulate(flat: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    starts = np.cumsum(lengths) - lengths
    per_poly = lengths - 2
    owner = np.repeat(np.arange(lengths.size), per_poly)
    first_tri = np.cumsum(per_poly) - per_poly
    k = np.arange(owner.size) - first_tri[owner] + 1
    base = starts[owner]
    F = np.stack([flat[base], flat[base + k], flat[base + k + 1]], axis=1)
    return F.astype(np.int64, copy=False), owner


def _merge_vertices(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn a triangle soup into an indexed mesh by merging identical positions.

    Parameters
    ----------
    P : ndarray of float64, shape (3 t, 3)
        Corner positions, three consecutive rows per triangle.

    Returns
    -------
    V : ndarray of float64, shape (n, 3)
        Distinct positions (exact equality), in order of first appearance.
    F : ndarray of int64, shape (t, 3)
        Triangles indexing ``V``.
    """
    uniq, first, inverse = np.unique(P, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return uniq[order], rank[inverse.reshape(-1)].reshape(-1, 3).astype(np.int64)


def _attribute_name(raw: str) -> str:
    """Map a file's property name to a valid attribute name (an identifier)."""
    if raw.isidentifier():
        return raw
    cleaned = "".join(c if (c.isascii() and c.isalnum()) else "_" for c in raw)
    return cleaned if cleaned.isidentifier() else f"p_{cleaned}"


def _build_mesh(path: Path, arrays: _Arrays, name: str) -> Mesh:
    """Check for an empty surface and validate, naming the file in every error."""
    V, F, vattrs, fattrs = arrays
    if V.shape[0] == 0:
        raise _error(path, "has no vertices", "the file holds no geometry; re-export the mesh")
    if F.shape[0] == 0:
        raise _error(
            path,
            "has no faces; igljoin needs a triangle surface",
            f"the file holds only {V.shape[0]} vertices (a point cloud); "
            "export the surface with its faces",
        )
    try:
        return Mesh(V, F, vattrs, fattrs, name=name)
    except MeshReadError:
        raise
    except MeshError as exc:
        raise MeshReadError(
            f"{path}: the file was parsed but does not hold a valid mesh: {exc}"
        ) from None


# --------------------------------------------------------------------------- OBJ


def _obj_lines(text: str):
    """Yield ``(line_number, tokens)`` of non-empty records, joining ``\\`` continuations."""
    pending: list[str] = []
    start = 0
    for number, raw in enumerate(_lines(text), 1):
        line = raw.split("#", 1)[0].rstrip()
        if not pending:
            start = number
        if line.endswith("\\"):
            pending.append(line[:-1])
            continue
        tokens = " ".join([*pending, line]).split()
        pending = []
        if tokens:
            yield start, tokens
    if pending and " ".join(pending).split():
        yield start, " ".join(pending).split()


def _obj_vertex(path: Path, number: int, tokens: list[str]) -> tuple[float, float, float]:
    if len(tokens) < 4:
        raise _error(
            path,
            f"line {number}: vertex record has {len(tokens) - 1} coordinates, needs 3",
            "write vertices as 'v x y z'",
        )
    try:
        return float(tokens[1]), float(tokens[2]), float(tokens[3])
    except ValueError:
        raise _error(
            path,
            f"line {number}: vertex coordinates {' '.join(tokens[1:4])!r} are not numbers",
            "the file is corrupt; re-export it",
        ) from None


def _obj_face(path: Path, number: int, tokens: list[str], n_seen: int) -> list[int]:
    """Parse ``f`` corners (``a``, ``a/b``, ``a//c``, ``a/b/c``) to 0-based indices."""
    if len(tokens) < 4:
        raise _error(
            path,
            f"line {number}: face has {len(tokens) - 1} vertices; a face needs at least 3",
            "remove degenerate faces or re-export the mesh",
        )
    out = []
    for corner in tokens[1:]:
        try:
            i = int(corner.split("/", 1)[0])
        except ValueError:
            raise _error(
                path,
                f"line {number}: face corner {corner!r} is not a vertex index",
                "write faces as 'f a b c' with 1-based integer indices",
            ) from None
        if i == 0:
            raise _error(
                path,
                f"line {number}: face uses vertex index 0, but OBJ indices start at 1",
                "re-export the mesh with 1-based indices",
            )
        if i > _INDEX_LIMIT:
            raise _error(
                path,
                f"line {number}: face references vertex {i}, far beyond any vertex count",
                "the file is corrupt; re-export it",
            )
        if i < 0 and n_seen + i < 0:
            raise _error(
                path,
                f"line {number}: relative index {i} points before the first vertex "
                f"({n_seen} vertices are defined above it)",
                "the file is truncated or corrupt; re-export it",
            )
        out.append(i - 1 if i > 0 else n_seen + i)
    return out


def _read_obj(path: Path) -> _Arrays:
    """Read ``v`` and ``f`` records of an OBJ file (all other records are ignored)."""
    text = _read_text(path, "OBJ")
    verts: list[tuple[float, float, float]] = []
    flat: list[int] = []
    lengths: list[int] = []
    face_lines: list[int] = []
    for number, tokens in _obj_lines(text):
        if tokens[0] == "v":
            verts.append(_obj_vertex(path, number, tokens))
        elif tokens[0] == "f":
            corners = _obj_face(path, number, tokens, len(verts))
            flat.extend(corners)
            lengths.append(len(corners))
            face_lines.append(number)
    if not verts and not lengths:
        raise _error(
            path,
            "contains no OBJ vertex ('v') or face ('f') records",
            "check that it is really an OBJ mesh file",
        )
    V = np.array(verts, dtype=np.float64).reshape(-1, 3)
    flat_a = np.array(flat, dtype=np.int64)
    lengths_a = np.array(lengths, dtype=np.int64)
    if flat_a.size and flat_a.max() >= V.shape[0]:
        bad = int(np.flatnonzero(flat_a >= V.shape[0])[0])
        poly = int(np.searchsorted(np.cumsum(lengths_a), bad, side="right"))
        raise _error(
            path,
            f"line {face_lines[poly]}: face references vertex {int(flat_a[bad]) + 1} but the "
            f"file defines only {V.shape[0]} vertices",
            "the file is truncated or corrupt; re-export it",
        )
    F, _ = _fan_triangulate(flat_a, lengths_a)
    return V, F, {}, {}


# --------------------------------------------------------------------------- OFF


def _off_records(text: str) -> list[tuple[int, list[str]]]:
    """Non-empty lines of an OFF file with comments removed, as ``(number, tokens)``."""
    out = []
    for number, raw in enumerate(_lines(text), 1):
        tokens = raw.split("#", 1)[0].split()
        if tokens:
            out.append((number, tokens))
    return out


def _off_header(path: Path, records: list) -> tuple[int, int, int]:
    """Return ``(n_vertices, n_faces, first_data_record)`` from the OFF header."""
    keyword = records[0][1][0] if records else ""
    prefix = keyword[:-3]
    if not keyword.endswith("OFF") or set(prefix) - set("STCN"):
        raise _error(
            path,
            f"does not start with the 'OFF' keyword (found {keyword[:20]!r})",
            "check that it is really an OFF mesh file",
        )
    rest = records[0][1][1:]
    if rest and rest[0].upper() == "BINARY":
        raise _error(path, "is a binary OFF file, which is not supported", "save it as text OFF")
    first = 1
    if not rest:
        if len(records) < 2:
            raise _error(path, "ends after the 'OFF' keyword", "the file is truncated; re-export")
        rest, first = records[1][1], 2
    try:
        n_v, n_f = int(rest[0]), int(rest[1])
    except (ValueError, IndexError):
        raise _error(
            path,
            f"line {records[first - 1][0]}: expected vertex and face counts, found "
            f"{' '.join(rest)[:40]!r}",
            "the header must be 'OFF' then 'n_vertices n_faces n_edges'",
        ) from None
    if n_v < 0 or n_f < 0:
        raise _error(path, f"declares negative counts ({n_v}, {n_f})", "the file is corrupt")
    return n_v, n_f, first


def _off_vertices(path: Path, records: list) -> np.ndarray:
    out = np.empty((len(records), 3), dtype=np.float64)
    for row, (number, tokens) in enumerate(records):
        try:
            out[row] = [float(t) for t in tokens[:3]]
        except ValueError:
            raise _error(
                path,
                f"line {number}: vertex {' '.join(tokens[:3])!r} is not three numbers",
                "the file is truncated or corrupt; re-export it",
            ) from None
    return out


def _off_faces(path: Path, records: list) -> tuple[np.ndarray, np.ndarray]:
    flat: list[int] = []
    lengths = np.empty(len(records), dtype=np.int64)
    for row, (number, tokens) in enumerate(records):
        try:
            k = int(tokens[0])
            corners = [int(t) for t in tokens[1 : 1 + k]]
        except ValueError:
            raise _error(
                path,
                f"line {number}: face {' '.join(tokens)[:40]!r} is not a list of integers",
                "faces must read 'k i_1 ... i_k'; the file is corrupt",
            ) from None
        if k < 3 or len(corners) != k:
            raise _error(
                path,
                f"line {number}: face declares {k} vertices and lists {len(corners)}; "
                "a face needs at least 3",
                "the file is truncated or corrupt; re-export it",
            )
        flat.extend(corners)
        lengths[row] = k
    return np.array(flat, dtype=np.int64), lengths


def _read_off(path: Path) -> _Arrays:
    """Read an ASCII OFF file (also COFF/NOFF/...: extra per-vertex values are ignored)."""
    records = _off_records(_read_text(path, "OFF"))
    n_v, n_f, first = _off_header(path, records)
    available = len(records) - first
    if available < n_v + n_f:
        raise _error(
            path,
            f"declares {n_v} vertices and {n_f} faces but only {available} data lines "
            "follow; the file is truncated",
            "re-export or re-download the file",
        )
    V = _off_vertices(path, records[first : first + n_v])
    flat, lengths = _off_faces(path, records[first + n_v : first + n_v + n_f])
    if n_f == 0:
        return V, np.empty((0, 3), dtype=np.int64), {}, {}
    F, _ = _fan_triangulate(flat, lengths)
    return V, F, {}, {}


# --------------------------------------------------------------------------- STL


def _stl_binary_count(data: bytes) -> int | None:
    """Triangle count if ``data`` has exactly the size a binary STL needs, else None."""
    if len(data) < _STL_HEADER_BYTES + 4:
        return None
    count = int(np.frombuffer(data, dtype="<u4", count=1, offset=_STL_HEADER_BYTES)[0])
    expected = _STL_HEADER_BYTES + 4 + count * _STL_RECORD.itemsize
    return count if expected == len(data) else None


def _read_stl_binary(data: bytes, count: int) -> np.ndarray:
    records = np.frombuffer(data, dtype=_STL_RECORD, count=count, offset=_STL_HEADER_BYTES + 4)
    return records["vertices"].reshape(-1, 3).astype(np.float64)


def _read_stl_ascii(path: Path, text: str) -> np.ndarray:
    """Corner positions (3 t, 3) of an ASCII STL; facets must be closed triangles."""
    corners: list[tuple[float, float, float]] = []
    in_loop, loop_size, closed = False, 0, False
    for number, raw in enumerate(_lines(text), 1):
        tokens = raw.split()
        if not tokens:
            continue
        key = tokens[0].lower()
        if key == "vertex":
            try:
                corners.append((float(tokens[1]), float(tokens[2]), float(tokens[3])))
            except (ValueError, IndexError):
                raise _error(
                    path,
                    f"line {number}: {raw.strip()[:50]!r} is not 'vertex x y z'",
                    "the file is truncated or corrupt; re-export it",
                ) from None
            loop_size += 1
        elif key == "outer":
            in_loop, loop_size = True, 0
        elif key == "endloop":
            if loop_size != 3:
                raise _error(
                    path,
                    f"line {number}: facet has {loop_size} vertices; STL facets are triangles",
                    "re-export the mesh as triangles",
                )
            in_loop = False
        elif key == "endsolid":
            closed = True
    if in_loop or not closed:
        raise _error(
            path,
            "ASCII STL ends before 'endsolid'; the file is truncated",
            "re-export or re-download the file",
        )
    return np.array(corners, dtype=np.float64).reshape(-1, 3)


def _read_stl(path: Path) -> _Arrays:
    """Read binary or ASCII STL and merge identical corner positions into vertices."""
    with open(path, "rb") as fh:
        data = fh.read()
    count = _stl_binary_count(data)
    if count is not None:
        P = _read_stl_binary(data, count)
    elif data.lstrip()[:5].lower() == b"solid" and b"\0" not in data:
        P = _read_stl_ascii(path, data.decode("latin-1"))
    elif len(data) >= _STL_HEADER_BYTES + 4:
        declared = int(np.frombuffer(data, dtype="<u4", count=1, offset=_STL_HEADER_BYTES)[0])
        need = _STL_HEADER_BYTES + 4 + declared * _STL_RECORD.itemsize
        raise _error(
            path,
            f"binary STL header declares {declared} triangles ({need} bytes) but the file has "
            f"{len(data)} bytes; it is truncated or not an STL file",
            "re-export or re-download the file",
        )
    else:
        raise _error(
            path,
            f"is only {len(data)} bytes, too short for a binary STL, and is not ASCII STL",
            "check that it is really an STL file",
        )
    if P.shape[0] == 0:
        return np.empty((0, 3)), np.empty((0, 3), dtype=np.int64), {}, {}
    V, F = _merge_vertices(P)
    return V, F, {}, {}


# --------------------------------------------------------------------------- PLY


def _ply_parse(path: Path, fast: bool, text: bool) -> plyfile.PlyData:
    """Parse with plyfile; ``fast`` memory-maps binary triangle lists (read-only).

    ASCII files are opened in text mode here: plyfile would otherwise wrap the
    binary handle in a text wrapper that it never closes.
    """
    known = {"face": dict.fromkeys(_FACE_LIST_NAMES, 3)} if fast else {}
    opened = open(path, encoding="ascii") if text else open(path, "rb")
    with opened as fh, warnings.catch_warnings():
        # plyfile lets numpy warn about empty ASCII lists; those faces are reported below
        warnings.simplefilter("ignore", UserWarning)
        return plyfile.PlyData.read(fh, mmap="r", known_list_len=known)


def _ply_parse_error(path: Path, exc: Exception) -> MeshReadError:
    """Translate any plyfile/numpy/decoding failure into a clear MeshReadError."""
    detail = str(exc) or type(exc).__name__
    if isinstance(exc, plyfile.PlyHeaderParseError):
        return _error(path, f"has a malformed PLY header ({detail})", "re-export the file")
    if isinstance(exc, plyfile.PlyElementParseError) and exc.message == "early end-of-file":
        return _error(
            path,
            f"is truncated: the data ends before the header's counts are reached ({detail})",
            "re-export or re-download the file",
        )
    if isinstance(exc, plyfile.PlyElementParseError) and exc.message == "early end-of-line":
        return _error(
            path,
            f"is truncated or has a row with too few values ({detail})",
            "re-export or re-download the file",
        )
    if isinstance(exc, UnicodeDecodeError):
        return _error(
            path,
            "is declared ASCII PLY but contains non-ASCII bytes",
            "the file is corrupt; re-export it",
        )
    if isinstance(exc, MemoryError):
        return _error(
            path,
            "declares more elements than fit in memory; its header counts are corrupt",
            "re-export the file",
        )
    return _error(path, f"has malformed PLY data ({detail})", "the file is corrupt; re-export it")


def _ply_declared_counts(head: bytes) -> list[tuple[str, int]]:
    """``(element, count)`` of header elements that have properties (best effort).

    Parameters
    ----------
    head : bytes
        The start of the file, containing the whole header.

    Returns
    -------
    list of (str, int)
        Empty if the header cannot be read this way; plyfile then reports it.
    """
    end = head.find(b"end_header")
    if end < 0:
        return []
    out: list[tuple[str, int]] = []
    with_props: set[int] = set()
    for line in head[:end].decode("latin-1").splitlines():
        tokens = line.split()
        if len(tokens) == 3 and tokens[0] == "element" and tokens[2].isdigit():
            out.append((tokens[1], int(tokens[2])))
        elif tokens[:1] == ["property"] and out:
            with_props.add(len(out) - 1)
    return [item for i, item in enumerate(out) if i in with_props]


def _check_ply_start(path: Path) -> bool:
    """Refuse non-PLY files and headers whose counts cannot fit in the file.

    Returns True if the header declares the ASCII format.

    Every row of an element with properties takes at least one byte, in
    ASCII and in binary PLY, so a count larger than the file size means a
    truncated file or a corrupt header; checking first avoids allocating
    memory for it.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_PLY_HEADER_SCAN)
    if head[:3] != b"ply" or head[3:4] not in (b"\n", b"\r"):
        raise _error(
            path,
            f"does not start with the 'ply' magic line (found {head[:4]!r})",
            "check that it is really a PLY file",
        )
    for element, count in _ply_declared_counts(head):
        if count > size:
            raise _error(
                path,
                f"header declares {count} '{element}' rows but the file has only {size} bytes; "
                "the file is truncated or its header is corrupt",
                "re-export or re-download the file",
            )
    return b"\nformat ascii" in head.split(b"end_header", 1)[0]


def _read_ply_data(path: Path) -> plyfile.PlyData:
    """Parse a PLY file, memory-mapping binary triangle data when possible."""
    text = _check_ply_start(path)
    try:
        return _ply_parse(path, fast=True, text=text)
    except plyfile.PlyElementParseError as exc:
        if "unexpected list length" not in exc.message:
            raise _ply_parse_error(path, exc) from None
    except Exception as exc:  # any parser failure becomes a MeshReadError
        raise _ply_parse_error(path, exc) from None
    try:  # faces are not all triangles: read the variable-length lists row by row
        return _ply_parse(path, fast=False, text=text)
    except Exception as exc:  # any parser failure becomes a MeshReadError
        raise _ply_parse_error(path, exc) from None


def _scalar_columns(element, skip: set) -> dict:
    """Float64 copies of every scalar property of ``element`` not in ``skip``."""
    out = {}
    for prop in element.properties:
        if prop.name in skip or isinstance(prop, plyfile.PlyListProperty):
            continue
        out[_attribute_name(prop.name)] = np.array(element.data[prop.name], dtype=np.float64)
    return out


def _ply_vertices(path: Path, ply: plyfile.PlyData) -> tuple[np.ndarray, dict]:
    names = [e.name for e in ply.elements]
    if "vertex" not in names:
        raise _error(path, "has no 'vertex' element", "this PLY file holds no mesh vertices")
    element = ply["vertex"]
    scalars = {p.name for p in element.properties if not isinstance(p, plyfile.PlyListProperty)}
    missing = [c for c in "xyz" if c not in scalars]
    if missing:
        raise _error(
            path,
            f"vertex element lacks the coordinate properties {missing}",
            "vertices need scalar properties x, y and z",
        )
    V = np.column_stack([np.asarray(element.data[c], dtype=np.float64) for c in "xyz"])
    return V.reshape(-1, 3), _scalar_columns(element, {"x", "y", "z"})


def _ply_polygons(path: Path, element, prop_name: str) -> tuple[np.ndarray, np.ndarray]:
    """Concatenated indices (s,) and polygon sizes (p,) of a face list property."""
    column = element.data[prop_name]
    if column.dtype != object:  # memory-mapped fixed-length lists: shape (p, k)
        lengths = np.full(column.shape[0], column.shape[1], dtype=np.int64)
        flat = column.reshape(-1)
    else:
        lengths = np.fromiter((len(r) for r in column), dtype=np.int64, count=column.shape[0])
        flat = np.concatenate([np.asarray(row).reshape(-1) for row in column])
    if not np.issubdtype(flat.dtype, np.integer):
        raise _error(
            path,
            f"face vertex indices are stored as {flat.dtype}, not integers",
            "re-export the mesh with integer face indices",
        )
    small = np.flatnonzero(lengths < 3)
    if small.size:
        raise _error(
            path,
            f"{small.size} faces have fewer than 3 vertices (first: face {int(small[0])} with "
            f"{int(lengths[small[0]])})",
            "remove degenerate faces; a face needs at least 3 vertices",
        )
    return flat.astype(np.int64), lengths


def _ply_faces(path: Path, ply: plyfile.PlyData) -> tuple[np.ndarray, dict]:
    names = [e.name for e in ply.elements]
    if "face" not in names or ply["face"].count == 0:
        return np.empty((0, 3), dtype=np.int64), {}
    element = ply["face"]
    lists = [p.name for p in element.properties if isinstance(p, plyfile.PlyListProperty)]
    found = [n for n in _FACE_LIST_NAMES if n in lists]
    if not found:
        raise _error(
            path,
            f"face element has no 'vertex_indices' list property (lists: {lists})",
            "re-export the mesh with standard PLY faces",
        )
    flat, lengths = _ply_polygons(path, element, found[0])
    F, owner = _fan_triangulate(flat, lengths)
    attrs = _scalar_columns(element, set())
    return F, {key: value[owner] for key, value in attrs.items()}


def _read_ply(path: Path) -> _Arrays:
    """Read vertices, faces and scalar properties of a PLY file through plyfile."""
    ply = _read_ply_data(path)
    V, vattrs = _ply_vertices(path, ply)
    F, fattrs = _ply_faces(path, ply)
    return V, F, vattrs, fattrs


_READERS: dict[str, Callable[[Path], _Arrays]] = {
    ".obj": _read_obj,
    ".off": _read_off,
    ".ply": _read_ply,
    ".stl": _read_stl,
}


def read_mesh(path: str | os.PathLike, *, name: str | None = None) -> Mesh:
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file.

    Parameters
    ----------
    path : str or os.PathLike
        The file. The format comes from its suffix (case-insensitive):
        ``.obj``, ``.off``, ``.ply`` or ``.stl``. It is opened read-only.
    name : str, optional
        Name of the returned mesh, used in error messages; defaults to the
        file name without its suffix.

    Returns
    -------
    Mesh
        ``V`` of shape (n, 3) float64 and ``F`` of shape (m, 3) int64.
        Polygons with more than 3 vertices (OBJ, OFF, PLY) are split into
        triangle fans ``(v0, v_k, v_k+1)``. For PLY, every scalar vertex
        property other than ``x, y, z`` (normals, colours, quality, ...)
        becomes ``vertex_attributes[name]`` of shape (n,) float64, and every
        scalar face property becomes ``face_attributes[name]`` of shape (m,)
        float64 (repeated for each triangle of a split polygon); list
        properties other than the face indices are ignored. STL corners with
        exactly equal coordinates are merged into one vertex, so the mesh is
        connected. OBJ texture coordinates, normals, groups and materials
        are ignored.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    MeshReadError
        If ``path`` is a directory or is empty, has an unsupported suffix, is
        not in the format its suffix claims, is truncated or corrupt, has no
        faces, or holds an invalid mesh (e.g. NaN coordinates or face indices
        out of range). The message names the file, the problem and the fix.

    Examples
    --------
    >>> mesh = read_mesh("host.ply")  # doctest: +SKIP
    >>> mesh.V.shape, mesh.F.shape  # doctest: +SKIP
    ((1872, 3), (3022, 3))
    """
    file = Path(path)
    _check_input_file(file)
    reader = _READERS[_format_of(file)]
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf are reported by validation
        arrays = reader(file)
    return _build_mesh(file, arrays, name if name is not None else file.stem)


# --------------------------------------------------------------------------- writers


def _write_obj(tmp: Path, mesh: Mesh) -> None:
    """Text OBJ with ``%.17g`` coordinates (exact float64 round trip)."""
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"# written by igljoin: {mesh.n_vertices} vertices, {mesh.n_faces} faces\n")
        np.savetxt(fh, mesh.V, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, mesh.F + 1, fmt="f %d %d %d")


def _write_off(tmp: Path, mesh: Mesh) -> None:
    """Text OFF with ``%.17g`` coordinates (exact float64 round trip)."""
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"OFF\n{mesh.n_vertices} {mesh.n_faces} 0\n")
        np.savetxt(fh, mesh.V, fmt="%.17g %.17g %.17g")
        np.savetxt(fh, mesh.F, fmt="3 %d %d %d")


def _face_normals(corners: np.ndarray) -> np.ndarray:
    """Unit normals (m, 3) of triangles given as corners (m, 3, 3); zero if degenerate."""
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _write_stl(tmp: Path, mesh: Mesh, binary: bool) -> None:
    """Binary STL (float32 coordinates) or ASCII STL (``%.17g``, exact)."""
    corners = mesh.V[mesh.F]
    normals = _face_normals(corners)
    if binary:
        records = np.zeros(mesh.n_faces, dtype=_STL_RECORD)
        records["normal"] = normals
        records["vertices"] = corners
        with open(tmp, "wb") as fh:
            fh.write(b"binary STL written by igljoin".ljust(_STL_HEADER_BYTES, b" "))
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


def _ply_type(key: str, values: np.ndarray, kind: str) -> str:
    """PLY storage type of an attribute: f8 for floats, i4 for ints, u1 for bools."""
    if values.dtype == np.bool_:
        return "u1"
    if np.issubdtype(values.dtype, np.integer):
        if values.size == 0 or (values.min() >= _INT32.min and values.max() <= _INT32.max):
            return "i4"
        return "f8"
    if np.issubdtype(values.dtype, np.floating):
        return "f8"
    raise MeshError(
        f"{kind} attribute {key!r} has dtype {values.dtype}, which PLY cannot store; "
        "convert it to a numeric or bool array, or drop it before writing"
    )


def _ply_columns(attrs: Mapping, count: int, kind: str, reserved: set) -> list:
    """Flatten attributes into PLY scalar columns ``(name, type, values (count,))``."""
    columns = []
    for key, value in attrs.items():
        a = np.asarray(value)
        ply_type = _ply_type(key, a, kind)
        if a.ndim == 1:
            named = [(key, a)]
        else:
            flat = a.reshape(count, -1)
            named = [(f"{key}_{j}", flat[:, j]) for j in range(flat.shape[1])]
        for column_name, column in named:
            if column_name in reserved:
                raise MeshError(
                    f"{kind} attribute {key!r} would be written as PLY property "
                    f"{column_name!r}, which is already used; rename the attribute"
                )
            reserved.add(column_name)
            columns.append((column_name, ply_type, column))
    return columns


def _structured(columns: list, count: int) -> np.ndarray:
    """Pack ``(name, type, values)`` columns into a structured array of length ``count``."""
    dtype = [
        (name, ply_type) if np.ndim(values) == 1 else (name, ply_type, np.shape(values)[1:])
        for name, ply_type, values in columns
    ]
    out = np.empty(count, dtype=dtype)
    for name, _, values in columns:
        out[name] = values
    return out


def _ply_document(mesh: Mesh, binary: bool) -> plyfile.PlyData:
    """Build the plyfile document: vertex x, y, z (f8) + attributes; face indices + attributes."""
    vertex_cols = [(c, "f8", mesh.V[:, j]) for j, c in enumerate("xyz")]
    vertex_cols += _ply_columns(mesh.vertex_attributes, mesh.n_vertices, "vertex", {"x", "y", "z"})
    face_cols = [("vertex_indices", "i4", mesh.F)]
    face_cols += _ply_columns(mesh.face_attributes, mesh.n_faces, "face", {"vertex_indices"})
    vertex = plyfile.PlyElement.describe(_structured(vertex_cols, mesh.n_vertices), "vertex")
    face = plyfile.PlyElement.describe(
        _structured(face_cols, mesh.n_faces),
        "face",
        len_types={"vertex_indices": "u1"},
        val_types={"vertex_indices": "i4"},
    )
    return plyfile.PlyData(
        [vertex, face], text=not binary, byte_order="<", comments=["written by igljoin"]
    )


def write_mesh(path: str | os.PathLike, mesh: Mesh, *, binary: bool = True) -> Path:
    """Write a triangle mesh to an OBJ, OFF, PLY or STL file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; the format comes from its suffix (case-insensitive):
        ``.obj``, ``.off``, ``.ply`` or ``.stl``. Its directory must exist. An
        existing file is replaced only once the new one is completely written.
    mesh : Mesh or tuple of (array_like (n, 3), array_like (m, 3))
        The mesh to write.
    binary : bool, optional
        Binary (default) or ASCII encoding for PLY and STL. OBJ and OFF are
        always text.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    MeshError
        If the suffix is not supported, or a PLY attribute cannot be stored
        (non-numeric dtype, or a name clashing with another property).
    FileNotFoundError
        If the output directory does not exist.
    OSError
        On file-system failures; a full disk gives a message that says so.
        No partial file is left behind in any case.

    Notes
    -----
    * PLY keeps attributes: ``x, y, z`` and float attributes are stored as
      float64 (exact round trip), integer attributes as int32 (float64 if a
      value does not fit in int32), bool attributes as uint8. An attribute of
      shape (n, k) is stored as the properties ``name_0 .. name_{k-1}`` (read
      back as separate scalar attributes); shape (n, k, l, ...) is flattened
      the same way. Faces are ``property list uchar int vertex_indices``.
    * OBJ, OFF and STL cannot hold attributes: they are silently dropped.
    * OBJ, OFF and ASCII STL write coordinates with 17 significant digits, so
      they read back exactly; binary STL stores float32 coordinates and
      repeats shared vertices per triangle (they are merged again on reading).
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise MeshError(
            f"cannot write {target}: unsupported suffix {target.suffix or '(none)'!r}; "
            f"use one of {_supported()}"
        )
    m = as_mesh(mesh)
    document = _ply_document(m, binary) if suffix == ".ply" else None
    with atomic_path(target) as tmp:
        if document is not None:
            document.write(str(tmp))
        elif suffix == ".obj":
            _write_obj(tmp, m)
        elif suffix == ".off":
            _write_off(tmp, m)
        else:
            _write_stl(tmp, m, binary)
    return target
