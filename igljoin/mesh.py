"""The validated triangle mesh type and the checks a joinable mesh must pass."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import MeshError

__all__ = ["Mesh", "as_mesh", "MAX_ELEMENTS"]

#: Default guard on mesh size (vertices or faces); larger meshes are refused
#: with a clear error before memory runs out. Change with ``igljoin.mesh.MAX_ELEMENTS``.
MAX_ELEMENTS = 20_000_000


def _readonly(a: np.ndarray) -> np.ndarray:
    """A C-ordered read-only copy (the caller's array and its flags stay untouched)."""
    a = np.array(a, order="C", copy=True)
    a.flags.writeable = False
    return a


def _check_rows(A: np.ndarray, name: str, array: str, rows: str, layout: str, what: str) -> None:
    """Refuse ``A`` unless it is a ``(rows, 3)`` table within the size guard.

    Parameters
    ----------
    A : ndarray
        The vertex or face array as given.
    name : str
        Mesh name, first in every message.
    array, rows, layout, what : str
        How the messages name the array (``"vertex array V"``), its row count
        (``"n"``), what a row holds and what its rows are (``"vertices"``).
    """
    if A.ndim != 2 or A.shape[1] != 3:
        raise MeshError(f"{name}: {array} has shape {A.shape}; it must be ({rows}, 3) ({layout})")
    if A.shape[0] > MAX_ELEMENTS:
        raise MeshError(
            f"{name}: {A.shape[0]:,} {what} exceed the size guard of {MAX_ELEMENTS:,}; "
            "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS"
        )


def _vertices(V: Any, name: str) -> np.ndarray:
    try:
        complex_input = np.iscomplexobj(np.asarray(V))
    except (TypeError, ValueError):
        complex_input = False
    if complex_input:
        raise MeshError(f"{name}: vertex array V is complex; pass real (n, 3) coordinates")
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeshError(
            f"{name}: vertex array V cannot be converted to float64 ({exc}); "
            "pass an (n, 3) array of coordinates"
        ) from None
    _check_rows(V, name, "vertex array V", "n", "one row of x, y, z per vertex", "vertices")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise MeshError(
            f"{name}: {idx.size} vertices have NaN or infinite coordinates "
            f"(first: {idx[:5].tolist()}); remove or repair them before joining"
        )
    return V


def _faces(F: Any, n: int, name: str) -> np.ndarray:
    try:
        Fa = np.asarray(F)
    except (TypeError, ValueError) as exc:
        raise MeshError(
            f"{name}: face array F cannot be read ({exc}); pass an (m, 3) int array"
        ) from None
    if Fa.size == 0:
        raise MeshError(f"{name}: the mesh has no faces; pass at least one triangle in F")
    _check_rows(Fa, name, "face array F", "m", "triangles; triangulate polygons first", "faces")
    if not np.issubdtype(Fa.dtype, np.integer):
        if (
            np.issubdtype(Fa.dtype, np.floating)
            and np.isfinite(Fa).all()
            and (Fa == np.round(Fa)).all()
        ):
            Fa = Fa.astype(np.int64)
        else:
            raise MeshError(
                f"{name}: face array F has dtype {Fa.dtype}; it must hold integer vertex indices"
            )
    Fa = Fa.astype(np.int64, copy=False)
    lo, hi = int(Fa.min()), int(Fa.max())
    if lo < 0 or hi >= n:
        raise MeshError(
            f"{name}: face indices range over [{lo}, {hi}] but there are {n} vertices; "
            f"every index must be in [0, {n - 1}] (indices are 0-based)"
        )
    return Fa


def _attributes(attrs: Mapping[str, Any] | None, count: int, kind: str, name: str) -> dict:
    out: dict[str, np.ndarray] = {}
    for key, value in (attrs or {}).items():
        a = np.asarray(value)
        if a.shape[:1] != (count,):
            raise MeshError(
                f"{name}: {kind} attribute '{key}' has shape {a.shape}; it needs one value "
                f"per {kind} ({count})"
            )
        if not isinstance(key, str) or not key.isidentifier():
            raise MeshError(
                f"{name}: attribute name {key!r} is not a plain identifier; use letters, "
                "digits and underscores"
            )
        out[str(key)] = _readonly(a)
    return out


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh with validated, read-only arrays.

    Parameters
    ----------
    V : array_like, shape (n, 3)
        Vertex coordinates, converted to float64. Must be finite.
    F : array_like, shape (m, 3)
        Triangle vertex indices, converted to int64, each in ``[0, n)``.
    vertex_attributes : mapping of str to array_like, shape (n, ...), optional
        Per-vertex scalar or vector data (written to PLY).
    face_attributes : mapping of str to array_like, shape (m, ...), optional
        Per-face data.
    name : str, optional
        Used in error messages.

    Notes
    -----
    Structural validity only (shapes, finiteness, index range). Topological
    requirements for joining (no degenerate faces, edge-manifold, ...) are
    checked where a mesh is joined, so that broken meshes can still be read,
    inspected and cleaned.

    Examples
    --------
    >>> import numpy as np, igljoin
    >>> m = igljoin.Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> m.V.shape, m.F.dtype
    ((3, 3), dtype('int64'))
    """

    V: np.ndarray
    F: np.ndarray
    vertex_attributes: dict = field(default_factory=dict)
    face_attributes: dict = field(default_factory=dict)
    name: str = "mesh"

    def __post_init__(self) -> None:
        V = _vertices(self.V, self.name)
        F = _faces(self.F, V.shape[0], self.name)
        object.__setattr__(self, "V", _readonly(V))
        object.__setattr__(self, "F", _readonly(F))
        object.__setattr__(
            self,
            "vertex_attributes",
            _attributes(self.vertex_attributes, V.shape[0], "vertex", self.name),
        )
        object.__setattr__(
            self,
            "face_attributes",
            _attributes(self.face_attributes, F.shape[0], "face", self.name),
        )

    @classmethod
    def _of_own_arrays(
        cls,
        V: np.ndarray,
        F: np.ndarray,
        vertex_attributes: dict | None = None,
        face_attributes: dict | None = None,
        name: str = "mesh",
    ) -> Mesh:
        """A mesh of arrays igljoin made itself, taken as they are: no checks, no copies.

        For a join's own meshes (its deformed and rest guest), whose arrays
        are already what the checks would make of them: ``V`` float64
        (n, 3) and finite, ``F`` int64 (m, 3) with indices in ``[0, n)``,
        attributes one row per vertex or face under identifier names, each
        array C-ordered and held by nothing that writes it. They are made
        read-only in place.
        """
        vertex_attributes = dict(vertex_attributes or {})
        face_attributes = dict(face_attributes or {})
        for a in (V, F, *vertex_attributes.values(), *face_attributes.values()):
            a.flags.writeable = False
        mesh = object.__new__(cls)
        for key, value in (
            ("V", V),
            ("F", F),
            ("vertex_attributes", vertex_attributes),
            ("face_attributes", face_attributes),
            ("name", name),
        ):
            object.__setattr__(mesh, key, value)
        return mesh

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return int(self.V.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces ``m``."""
        return int(self.F.shape[0])

    def with_attributes(self, vertex: Mapping | None = None, face: Mapping | None = None) -> Mesh:
        """Return a copy with extra attributes merged in (same geometry)."""
        return Mesh(
            self.V,
            self.F,
            {**self.vertex_attributes, **(vertex or {})},
            {**self.face_attributes, **(face or {})},
            name=self.name,
        )

    def __repr__(self) -> str:
        return f"Mesh(name={self.name!r}, n_vertices={self.n_vertices}, n_faces={self.n_faces})"


def as_mesh(obj: Any, name: str = "mesh") -> Mesh:
    """Accept a :class:`Mesh` or a ``(V, F)`` tuple and return a :class:`Mesh`.

    Parameters
    ----------
    obj : Mesh or tuple of (array_like (n, 3), array_like (m, 3))
        The mesh.
    name : str
        Argument name used in error messages.

    Returns
    -------
    Mesh
    """
    if isinstance(obj, Mesh):
        return obj
    if isinstance(obj, (tuple, list)) and len(obj) == 2:
        return Mesh(obj[0], obj[1], name=name)
    raise MeshError(
        f"{name}: expected an igljoin.Mesh or a (V, F) tuple, got {type(obj).__name__}; "
        "read a file with igljoin.read_mesh(path) or pass (V, F) arrays"
    )
