"""PLY reading and writing, with vectorised ASCII fast paths.

* Reading: :mod:`._ply_parse` reads the header and every element, ASCII or
  binary (little or big endian), any property types and list count types;
  binary elements with rows of one size (triangle faces) in one
  :func:`numpy.frombuffer` call. ASCII PLY whose header is a plain
  ``vertex`` + ``face`` layout (scalar properties, one face list of
  triangles) is parsed here with vectorised numpy; any other file, and any
  file the fast path declines, goes to the row-by-row reader, which gives
  every error message.
* Writing: binary little-endian from packed numpy records, or ASCII with
  :func:`numpy.savetxt` (``%.17g``, exact).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshReadError
from ..mesh import Mesh
from ._common import (
    FLOAT_BYTES,
    Arrays,
    attribute_name,
    error,
    fan_triangulate,
    max_elements,
    parse_numbers,
    scan,
    split_lines,
)
from ._ply_parse import (
    PLY_TYPES,
    Element,
    Header,
    HeaderError,
    Property,
    RowError,
    parse_header,
    read_elements,
)

_FACE_LIST_NAMES = ("vertex_indices", "vertex_index")
_INT32 = np.iinfo(np.int32)
_PLY_HEADER_SCAN = 1 << 20  # bytes read to find the PLY header (headers are far smaller)
_PLY_NAMES = {"i1": "char", "u1": "uchar", "i4": "int", "f8": "double"}


def _ply_parse_error(path: Path, exc: Exception) -> MeshReadError:
    """Translate a header, row or decoding failure into a clear MeshReadError."""
    detail = str(exc) or type(exc).__name__
    if isinstance(exc, HeaderError):
        return error(path, f"has a malformed PLY header ({detail})", "re-export the file")
    if isinstance(exc, RowError) and exc.kind == "eof":
        return error(
            path,
            f"is truncated: the data ends before the header's counts are reached ({detail})",
            "re-export or re-download the file",
        )
    if isinstance(exc, RowError) and exc.kind == "eol":
        return error(
            path,
            f"is truncated or has a row with too few values ({detail})",
            "re-export or re-download the file",
        )
    if isinstance(exc, UnicodeDecodeError):
        return error(
            path,
            "is declared ASCII PLY but contains non-ASCII bytes",
            "the file is corrupt; re-export it",
        )
    if isinstance(exc, MemoryError):
        return error(
            path,
            "declares more elements than fit in memory; its header counts are corrupt",
            "re-export the file",
        )
    return error(path, f"has malformed PLY data ({detail})", "the file is corrupt; re-export it")


def _ply_declared_counts(head: bytes) -> list[tuple[str, int]]:
    """``(element, count)`` of header elements that have properties (best effort).

    Parameters
    ----------
    head : bytes
        The start of the file, containing the whole header.

    Returns
    -------
    list of (str, int)
        Empty if the header cannot be read this way; the header parser then reports it.
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
        raise error(
            path,
            f"does not start with the 'ply' magic line (found {head[:4]!r})",
            "check that it is really a PLY file",
        )
    limit = max_elements()
    for element, count in _ply_declared_counts(head):
        if count > size:
            raise error(
                path,
                f"header declares {count} '{element}' rows but the file has only {size} bytes; "
                "the file is truncated or its header is corrupt",
                "re-export or re-download the file",
            )
        if element in ("vertex", "face") and count > limit:
            raise error(
                path,
                f"header declares {count:,} '{element}' rows, more than the size guard of "
                f"{limit:,}",
                "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS",
            )
    return b"\nformat ascii" in head.split(b"end_header", 1)[0]


def _read_ply_data(path: Path) -> tuple[Header, dict[str, dict]]:
    """The header and every element's properties (see :func:`._ply_parse.read_elements`)."""
    _check_ply_start(path)
    try:
        with open(path, "rb") as fh:
            header = parse_header(fh.read(_PLY_HEADER_SCAN))
            return header, read_elements(fh, header)
    except Exception as exc:  # any parser failure becomes a MeshReadError
        raise _ply_parse_error(path, exc) from None


def _scalar_columns(element: Element, values: dict, skip: set) -> dict:
    """Float64 copies of every scalar property of ``element`` not in ``skip``."""
    out = {}
    for prop in element.properties:
        if prop.name in skip or prop.is_list:
            continue
        out[attribute_name(prop.name)] = np.asarray(values[prop.name], dtype=np.float64)
    return out


def _element(header: Header, name: str) -> Element | None:
    """The first element called ``name``, or None."""
    return next((e for e in header.elements if e.name == name), None)


def _ply_vertices(path: Path, header: Header, data: dict) -> tuple[np.ndarray, dict]:
    element = _element(header, "vertex")
    if element is None:
        raise error(path, "has no 'vertex' element", "this PLY file holds no mesh vertices")
    scalars = {p.name for p in element.properties if not p.is_list}
    missing = [c for c in "xyz" if c not in scalars]
    if missing:
        raise error(
            path,
            f"vertex element lacks the coordinate properties {missing}",
            "vertices need scalar properties x, y and z",
        )
    values = data["vertex"]
    V = np.column_stack([np.asarray(values[c], dtype=np.float64) for c in "xyz"])
    return V.reshape(-1, 3), _scalar_columns(element, values, {"x", "y", "z"})


def _ply_polygons(path: Path, prop: Property, column: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Concatenated indices (s,) and polygon sizes (p,) of a face list property."""
    flat, lengths = column
    if np.dtype(prop.dtype).kind not in "iu":
        raise error(
            path,
            f"face vertex indices are stored as {np.dtype(prop.dtype)}, not integers",
            "re-export the mesh with integer face indices",
        )
    small = np.flatnonzero(lengths < 3)
    if small.size:
        raise error(
            path,
            f"{small.size} faces have fewer than 3 vertices (first: face {int(small[0])} with "
            f"{int(lengths[small[0]])})",
            "remove degenerate faces; a face needs at least 3 vertices",
        )
    return flat.astype(np.int64), lengths


def _ply_faces(path: Path, header: Header, data: dict) -> tuple[np.ndarray, dict]:
    element = _element(header, "face")
    if element is None or element.count == 0:
        return np.empty((0, 3), dtype=np.int64), {}
    lists = {p.name: p for p in element.properties if p.is_list}
    found = [n for n in _FACE_LIST_NAMES if n in lists]
    if not found:
        raise error(
            path,
            f"face element has no 'vertex_indices' list property (lists: {list(lists)})",
            "re-export the mesh with standard PLY faces",
        )
    values = data["face"]
    flat, lengths = _ply_polygons(path, lists[found[0]], values[found[0]])
    F, owner = fan_triangulate(flat, lengths)
    attrs = _scalar_columns(element, values, set())
    return F, {key: value[owner] for key, value in attrs.items()}


def read(path: Path) -> Arrays:
    """Read vertices, faces and scalar properties of a PLY file."""
    arrays = _read_ascii_fast(path)
    if arrays is not None:
        return arrays
    header, data = _read_ply_data(path)
    V, vattrs = _ply_vertices(path, header, data)
    F, fattrs = _ply_faces(path, header, data)
    return V, F, vattrs, fattrs


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


# --------------------------------------------------------------------------- ASCII fast paths

_FAST_ASCII_BYTES = 1 << 31  # larger ASCII files go to the row-by-row reader


def _ascii_header(data: bytes) -> tuple[int, list] | None:
    """``(body_offset, elements)`` of a plain ASCII PLY header, or None.

    ``elements`` is a list of ``(name, count, properties)`` where a property is
    ``(name, dtype)`` for a scalar and ``(name, "list", count_dtype, item_dtype)``.
    """
    end = data.find(b"\nend_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        return None
    elements: list = []
    for raw in data[:end].decode("latin-1").split("\n")[1:]:
        tokens = raw.split()
        if not tokens or tokens[0] in ("comment", "obj_info"):
            continue
        if tokens[0] == "format":
            if tokens[1:] != ["ascii", "1.0"]:
                return None
        elif tokens[0] == "element" and len(tokens) == 3 and tokens[2].isdigit():
            elements.append((tokens[1], int(tokens[2]), []))
        elif tokens[0] == "property" and elements and len(tokens) == 3:
            if tokens[1] not in PLY_TYPES:
                return None
            elements[-1][2].append((tokens[2], PLY_TYPES[tokens[1]]))
        elif tokens[0] == "property" and elements and len(tokens) == 5 and tokens[1] == "list":
            if tokens[2] not in PLY_TYPES or tokens[3] not in PLY_TYPES:
                return None
            elements[-1][2].append((tokens[4], "list", PLY_TYPES[tokens[2]], PLY_TYPES[tokens[3]]))
        else:
            return None
    return end + len(b"\nend_header\n"), elements


def _typed(column: np.ndarray, dtype: str) -> np.ndarray | None:
    """``column`` (float64) stored as ``dtype`` and read back as float64; None if it cannot be."""
    kind = np.dtype(dtype)
    if kind.kind in "iu":
        info = np.iinfo(kind)
        if not ((column == np.round(column)) & (column >= info.min) & (column <= info.max)).all():
            return None
    return column.astype(kind).astype(np.float64)


def _table(block: list[bytes], width: int) -> np.ndarray | None:
    """Rows of ``width`` numbers (float64, shape (rows, width)), or None if not exactly that."""
    blob = b"\n".join(block)
    scanned = scan(blob, FLOAT_BYTES)
    if scanned is None or not (scanned[0] == width).all():
        return None
    values = parse_numbers(blob, np.float64, len(block) * width)
    return None if values is None else values.reshape(len(block), width)


def _read_ascii_fast(path: Path) -> Arrays | None:
    """Vertices, triangles and scalar properties of a plain ASCII PLY, or None (read row by row)."""
    if not _check_ply_start(path) or path.stat().st_size > _FAST_ASCII_BYTES:
        return None  # binary, or too large for the fast path
    with open(path, "rb") as fh:
        data = fh.read()
    parsed = _ascii_header(data)
    if parsed is None or b"\r" in data or not data.endswith(b"\n"):  # cut mid-number?
        return None
    offset, elements = parsed
    names = [e[0] for e in elements]
    if names not in (["vertex"], ["vertex", "face"]):
        return None
    vprops = elements[0][2]
    fprops = elements[1][2] if len(elements) == 2 else []
    n_v, n_f = elements[0][1], (elements[1][1] if fprops else 0)
    if n_f == 0 or any(len(p) != 2 for p in vprops):
        return None
    if not {"x", "y", "z"} <= {p[0] for p in vprops}:
        return None
    if not fprops or fprops[0][0] not in _FACE_LIST_NAMES or len(fprops[0]) != 4:
        return None
    if any(len(p) != 2 for p in fprops[1:]) or np.dtype(fprops[0][3]).kind not in "iu":
        return None
    lines = split_lines(data[offset:])
    if len(lines) < n_v + n_f or any(line.strip() for line in lines[n_v + n_f :]):
        return None  # truncated, or more than the header declares: reported row by row
    vtable = _table(lines[:n_v], len(vprops))
    ftable = _table(lines[n_v : n_v + n_f], 4 + len(fprops) - 1)
    if vtable is None or ftable is None or not (ftable[:, 0] == 3).all():
        return None
    columns = {}
    for j, (name, dtype) in enumerate(vprops):
        columns[name] = _typed(vtable[:, j], dtype)
    faces = _typed(ftable[:, 1:4].reshape(-1), fprops[0][3])
    fattrs = {}
    for j, (name, dtype) in enumerate(fprops[1:], start=4):
        fattrs[attribute_name(name)] = _typed(ftable[:, j], dtype)
    if faces is None or any(c is None for c in (*columns.values(), *fattrs.values())):
        return None
    V = np.column_stack([columns.pop(c) for c in "xyz"])
    vattrs = {attribute_name(name): values for name, values in columns.items()}
    return V, faces.astype(np.int64).reshape(-1, 3), vattrs, fattrs


def _header_text(mesh: Mesh, vertex_cols: list, face_cols: list, encoding: str) -> str:
    lines = ["ply", f"format {encoding} 1.0", "comment written by igljoin"]
    lines.append(f"element vertex {mesh.n_vertices}")
    lines += [f"property {_PLY_NAMES[t]} {name}" for name, t, _ in vertex_cols]
    lines.append(f"element face {mesh.n_faces}")
    lines.append("property list uchar int vertex_indices")
    lines += [f"property {_PLY_NAMES[t]} {name}" for name, t, _ in face_cols]
    return "\n".join([*lines, "end_header"]) + "\n"


def _write_ascii(tmp: Path, mesh: Mesh) -> None:
    """ASCII PLY: ``%.17g`` floats (exact), integers as ``%d``; same header as binary."""
    vertex_cols = [(c, "f8", mesh.V[:, j]) for j, c in enumerate("xyz")]
    vertex_cols += _ply_columns(mesh.vertex_attributes, mesh.n_vertices, "vertex", {"x", "y", "z"})
    face_cols = _ply_columns(mesh.face_attributes, mesh.n_faces, "face", {"vertex_indices"})
    spec = {"f8": "%.17g", "i4": "%d", "u1": "%d"}
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(_header_text(mesh, vertex_cols, face_cols, "ascii"))
        table = np.column_stack([np.asarray(v, dtype=np.float64) for _, _, v in vertex_cols])
        np.savetxt(fh, table, fmt=[spec[t] for _, t, _ in vertex_cols])
        corners = np.column_stack([np.full(mesh.n_faces, 3), mesh.F])
        columns = [corners.astype(np.float64)]
        columns += [np.asarray(v, dtype=np.float64)[:, None] for _, _, v in face_cols]
        fmt = ["%d"] * 4 + [spec[t] for _, t, _ in face_cols]
        np.savetxt(fh, np.hstack(columns), fmt=fmt)


def _write_binary(tmp: Path, mesh: Mesh) -> None:
    """Binary little-endian PLY: one packed numpy record per vertex and per face."""
    vertex_cols = [(c, "f8", mesh.V[:, j]) for j, c in enumerate("xyz")]
    vertex_cols += _ply_columns(mesh.vertex_attributes, mesh.n_vertices, "vertex", {"x", "y", "z"})
    face_cols = _ply_columns(mesh.face_attributes, mesh.n_faces, "face", {"vertex_indices"})
    little = [(name, "<" + t, values) for name, t, values in vertex_cols]
    faces = [("count", "u1", np.full(mesh.n_faces, 3)), ("vertex_indices", "<i4", mesh.F)]
    faces += [(name, "<" + t, values) for name, t, values in face_cols]
    with open(tmp, "wb") as fh:
        fh.write(_header_text(mesh, vertex_cols, face_cols, "binary_little_endian").encode())
        fh.write(_structured(little, mesh.n_vertices).tobytes())
        fh.write(_structured(faces, mesh.n_faces).tobytes())


def write(tmp: Path, mesh: Mesh, binary: bool) -> None:
    """Write PLY, binary little-endian or ASCII (same header, same property types)."""
    if binary:
        _write_binary(tmp, mesh)
    else:
        _write_ascii(tmp, mesh)


def check_writable(mesh: Mesh) -> None:
    """Raise :class:`MeshError` before any file is opened if an attribute cannot be stored."""
    _ply_columns(mesh.vertex_attributes, mesh.n_vertices, "vertex", {"x", "y", "z"})
    _ply_columns(mesh.face_attributes, mesh.n_faces, "face", {"vertex_indices"})
