"""VTK output (``.vtu`` XML unstructured grid, ``.vtk`` legacy) through :mod:`meshio`.

Every per-vertex attribute becomes a named point-data array and every
per-face attribute a named cell-data array, so ParaView, VTK and meshio can
colour by them (ParaView's PLY reader keeps no custom properties). Arrays
keep their values exactly: float64 stays float64 and integers keep their
width; bool is stored as uint8 (VTK has no portable bool array). An
attribute of shape (n, k) is one array of k components (e.g. a vector); one
of shape (n, k, l, ...) is flattened to k * l * ... components.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import MeshError, missing_extra
from ..mesh import Mesh

#: ``file_format`` name of meshio for each suffix and the options igljoin writes with.
_FORMATS = {
    ".vtu": ("vtu", {"binary": True, "compression": "zlib"}),
    ".vtk": ("vtk42", {"binary": True}),
}


def _array(key: str, value: np.ndarray, count: int, kind: str) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype == np.bool_:
        a = a.astype(np.uint8)
    elif a.dtype == np.float16:
        a = a.astype(np.float32)
    elif not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise MeshError(
            f"{kind} attribute {key!r} has dtype {a.dtype}, which VTK cannot store; "
            "convert it to a numeric or bool array, or drop it before writing"
        )
    return np.ascontiguousarray(a.reshape(count, -1) if a.ndim > 2 else a)


def _arrays(attrs: Mapping, count: int, kind: str) -> dict:
    return {key: _array(key, value, count, kind) for key, value in attrs.items()}


def check_writable(mesh: Mesh) -> None:
    """Raise :class:`MeshError` before any file is opened if an attribute cannot be stored."""
    _arrays(mesh.vertex_attributes, mesh.n_vertices, "vertex")
    _arrays(mesh.face_attributes, mesh.n_faces, "face")


def write(tmp: Path, mesh: Mesh, suffix: str, *, binary: bool = True) -> None:
    """Write ``mesh`` with all its attributes to ``tmp`` as VTU or legacy VTK."""
    try:
        import meshio
    except ImportError:  # pragma: no cover - meshio is a core dependency
        raise missing_extra("meshio", "vtk", f"writing {suffix} files") from None
    file_format, options = _FORMATS[suffix]
    options = {**options, "binary": binary}
    if not binary:
        options.pop("compression", None)
    out = meshio.Mesh(
        np.asarray(mesh.V, dtype=np.float64),
        [("triangle", np.asarray(mesh.F, dtype=np.int64))],
        point_data=_arrays(mesh.vertex_attributes, mesh.n_vertices, "vertex"),
        cell_data={
            key: [value]
            for key, value in _arrays(mesh.face_attributes, mesh.n_faces, "face").items()
        },
    )
    meshio.write(str(tmp), out, file_format=file_format, **options)
