"""Cross-seam frames of a surface along one of its boundary curves.

At a boundary vertex ``q`` with curve tangent ``T`` and surface normal ``n``,
the *inward direction* ``h`` is the unit surface tangent perpendicular to the
curve, pointing into the surface (paper §4.4: ``t(q) = n(q) × (q − q₁)``,
with its sign fixed geometrically). A surface continued smoothly across the
boundary leaves ``q`` along ``−h``.

Two estimates are offered: the paper's one-ring estimate (faces incident to
``q``, neighbouring curve vertices for ``T``), and a smoothed one that
averages face normals over a ball of radius ``radius`` around ``q`` and takes
``T`` over a matching span of the curve, which is what makes the smooth join
robust on noisy scans.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .polyline import mean_segment

__all__ = [
    "CurveFaces",
    "SeamFrames",
    "curve_faces",
    "curve_frames",
    "face_normals_areas",
    "face_areas",
    "face_cross_products",
    "faces_at",
    "seam_frames",
    "vertex_face_matrix",
    "unit",
]


@dataclass(frozen=True)
class SeamFrames:
    """Frames at the vertices of a boundary curve.

    Attributes
    ----------
    normal : ndarray, shape (k, 3)
        Unit surface normal (sign follows the face orientation).
    tangent : ndarray, shape (k, 3)
        Unit curve tangent, in curve order.
    inward : ndarray, shape (k, 3)
        Unit surface tangent perpendicular to the curve, into the surface.
    """

    normal: np.ndarray
    tangent: np.ndarray
    inward: np.ndarray


def unit(X: np.ndarray) -> np.ndarray:
    """Rows of ``X`` (shape (k, 3)) scaled to unit length (zero rows stay zero)."""
    n = np.linalg.norm(X, axis=1, keepdims=True)
    return X / np.where(n > 0, n, 1.0)


def face_normals_areas(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit face normals and areas.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int, shape (m, 3)

    Returns
    -------
    normals : ndarray, shape (m, 3)
        ``c = (V[F[:, 1]] − V[F[:, 0]]) × (V[F[:, 2]] − V[F[:, 0]])`` over
        ``|c|``; zero-area faces get zero normals.
    areas : ndarray, shape (m,)
        ``|c| / 2``.

    Notes
    -----
    Computed coordinate by coordinate on contiguous arrays of shape (m,)
    with the operations, in the order, of ``np.cross`` (each component one
    rounded product minus another) and ``np.linalg.norm(c, axis=1)`` (the
    squares summed left to right), so the values are those of that
    row-wise formulation, to the last bit. Kept for its speed, measured on
    the arguments the joins pass (23 calls per join; medians on this
    machine): 0.74-1.55 ms in all against 2.2-5.6 ms with ``np.cross``,
    +1.5 ms of a 31 ms half-resolution paper join (4.7 %), +2.5 to +4.1 ms
    of a 176-189 ms paper join (1.4-2.1 %); in joins run two at a time on
    two busy cores, going back to ``np.cross`` made paper joins about 4 %
    slower (median of 84 paired joins).
    """
    return _normals_areas(face_cross_products(V, F))


def _normals_areas(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Face normals (m, 3), C-ordered, and areas (m,) of edge cross products ``c`` (3, m)."""
    length = _lengths(c)
    normals = c / np.where(length > 0, length, 1.0)
    return np.ascontiguousarray(normals.T), 0.5 * length


def face_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Face areas, shape (m,): the second output of :func:`face_normals_areas` alone."""
    return 0.5 * _lengths(face_cross_products(V, F))


def _lengths(c: np.ndarray) -> np.ndarray:
    """Length of each column of ``c`` (shape (3, m) -> (m,)), squares summed left to right."""
    if not np.issubdtype(c.dtype, np.inexact):
        c = c.astype(np.float64)  # as np.linalg.norm converts integer input
    sq = c * c
    return np.sqrt((sq[0] + sq[1]) + sq[2])


def face_cross_products(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Edge cross product of each face ``F`` (m, 3) of ``V`` (n, 3), coordinate-major (3, m).

    Row ``i`` is coordinate ``i`` of
    ``(V[F[:, 1]] − V[F[:, 0]]) × (V[F[:, 2]] − V[F[:, 0]])``: twice the area
    times the unit normal, rounded as ``np.cross`` rounds it (in the dtype
    of ``V``).
    """
    VT = np.ascontiguousarray(np.asarray(V).T)  # (3, n)
    FT = np.ascontiguousarray(np.asarray(F).T)  # (3, m)
    p0 = np.take(VT, FT[0], axis=1)  # (3, m) corner positions
    return _cross(np.take(VT, FT[1], axis=1) - p0, np.take(VT, FT[2], axis=1) - p0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of the columns of ``a`` and ``b`` (3, m), in the layout of ``a``.

    Each coordinate is one rounded product less another, in the order and
    dtype of ``np.cross`` on the rows of ``a.T`` and ``b.T``, so the values
    are its values to the last bit, without its overhead on short arrays.
    """
    c = np.empty_like(a, dtype=np.result_type(a, b))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=c[i])
        c[i] -= a[k] * b[j]
    return c


def vertex_face_matrix(F: np.ndarray, n: int) -> sp.csr_matrix:
    """Incidence matrix of shape (n, m): entry (v, f) is 1 where face f uses vertex v."""
    m = len(F)
    return sp.csr_matrix(
        (np.ones(3 * m), (F.reshape(-1), np.repeat(np.arange(m), 3))), shape=(n, m)
    )


def _curve_incidence(F: np.ndarray, curve: np.ndarray, n: int) -> sp.csr_matrix:
    """The rows ``curve`` of ``vertex_face_matrix(F, n)``: how many corners of each face are there.

    Built directly in CSR form when no face repeats a vertex: the same
    matrix (rows in curve order, each row's faces ascending, every entry
    1.0), without the sparse row selection.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    curve : ndarray of int, shape (k,)
    n : int
        Number of vertices.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (k, m)
        Entry ``(i, f)`` is the number of corners of face ``f`` at
        ``curve[i]`` (1, but 2 or 3 for a face that repeats that vertex).
    """
    m = len(F)
    corner_vertex = np.asarray(F, dtype=np.int64).reshape(-1)
    if (
        m
        and (
            (corner_vertex[0::3] == corner_vertex[1::3])
            | (corner_vertex[1::3] == corner_vertex[2::3])
            | (corner_vertex[2::3] == corner_vertex[0::3])
        ).any()
    ):  # a face repeating a vertex: entries above 1, left to scipy
        return vertex_face_matrix(F, n)[curve].tocsr()
    order = np.argsort(corner_vertex, kind="stable")  # by vertex, faces ascending within
    faces = order // 3
    per_vertex = np.bincount(corner_vertex, minlength=n)
    first = np.cumsum(per_vertex) - per_vertex
    counts = per_vertex[curve]
    indptr = np.zeros(len(curve) + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    # entries of row i: faces[first[curve[i]] : first[curve[i]] + counts[i]]
    at = np.repeat(first[curve] - indptr[:-1], counts) + np.arange(indptr[-1])
    indices = faces[at]
    index_dtype = (
        np.int32 if max(m, len(curve), int(indptr[-1])) <= np.iinfo(np.int32).max else np.int64
    )
    return sp.csr_matrix(
        (np.ones(len(indices)), indices.astype(index_dtype), indptr.astype(index_dtype)),
        shape=(len(curve), m),
    )


def faces_at(F: np.ndarray, vertices: np.ndarray, n: int) -> np.ndarray:
    """The faces that use at least one of ``vertices``, in their order.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    vertices : ndarray of int, shape (k,)
    n : int
        Number of vertices (greater than every index in ``F`` and ``vertices``).

    Returns
    -------
    ndarray of int, shape (m', 3)
        The rows of ``F`` that hold one of ``vertices``.
    """
    F = np.asarray(F)
    mark = np.zeros(n, dtype=bool)
    mark[np.asarray(vertices).reshape(-1)] = True
    FT = np.ascontiguousarray(F.T)
    return F[mark[FT[0]] | mark[FT[1]] | mark[FT[2]]]


def _curve_tangents(P: np.ndarray, closed: bool, span: int) -> np.ndarray:
    k = len(P)
    idx = np.arange(k)
    if closed:
        fwd, bwd = (idx + span) % k, (idx - span) % k
    else:
        fwd, bwd = np.minimum(idx + span, k - 1), np.maximum(idx - span, 0)
    return unit(P[fwd] - P[bwd])


class CurveFaces(NamedTuple):
    """Everything :func:`seam_frames` takes from a surface along a curve but its positions.

    Made once (:func:`curve_faces`), it gives the frames of the same faces
    at any positions of the surface (:func:`curve_frames`), with the curve's
    points and tangents as they were made: those of
    ``seam_frames(V, ..., curve_points=points)``. A curve that moves needs a
    new one.

    Attributes
    ----------
    faces : ndarray of int, shape (m', 3)
        The faces at the curve, in their order (:func:`faces_at`).
    incidence : scipy.sparse.csr_matrix, shape (k, m')
        Entry ``(i, f)`` the number of corners of ``faces[f]`` at the
        ``i``-th curve vertex: rows in curve order, each row's faces
        ascending. Times the face areas, the weights of the face normals
        and centroids.
    points : ndarray, shape (k, 3)
        The curve's positions.
    tangent : ndarray, shape (k, 3)
        Unit curve tangents there (:attr:`SeamFrames.tangent`).
    radius : float or None
        Smoothing radius, as given to :func:`seam_frames`.
    """

    faces: np.ndarray
    incidence: sp.csr_matrix
    points: np.ndarray
    tangent: np.ndarray
    radius: float | None


def curve_faces(
    F: np.ndarray,
    curve: np.ndarray,
    n: int,
    points: np.ndarray,
    closed: bool,
    *,
    radius: float | None = None,
) -> CurveFaces:
    """The parts of the frames along ``curve`` that do not depend on the positions.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    curve : ndarray of int, shape (k,)
        Ordered boundary vertices.
    n : int
        Number of vertices (greater than every index in ``F`` and ``curve``).
    points : ndarray, shape (k, 3)
        Positions for the curve tangents and the inward directions' signs
        (``V[curve]`` in :func:`seam_frames`, by default).
    closed : bool
    radius : float, optional
        Smoothing radius, as in :func:`seam_frames`.

    Returns
    -------
    CurveFaces
    """
    curve = np.asarray(curve)
    faces = faces_at(F, curve, n)
    span = 1
    if radius is not None and radius > 0:
        mean_edge = mean_segment(points, closed=False) if len(points) > 1 else radius
        span = int(np.clip(round(radius / max(mean_edge, 1e-300)), 1, max(1, len(points) // 4)))
    tangent = _curve_tangents(points, closed, span)
    return CurveFaces(faces, _curve_incidence(faces, curve, n), points, tangent, radius)


def curve_frames(V: np.ndarray, kept: CurveFaces) -> SeamFrames:
    """The frames of :func:`seam_frames` at positions ``V`` (n, 3), from ``curve_faces(...)``.

    The curve's points and tangents are the kept ones (``kept.points``,
    ``kept.tangent``). Only the corners of the faces at the curve are read
    (with a radius, the vertices within it as well). The normal at a
    curve vertex is the area-weighted mean of its faces' normals (or, with a
    radius, the quadric fit's); the inward direction ``unit(normal ×
    tangent)`` points towards the area-weighted mean of its faces'
    centroids.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    kept : CurveFaces
        Of the faces of ``V`` (:func:`curve_faces`).

    Returns
    -------
    SeamFrames
    """
    F, incidence, P, T, radius = kept
    corners = V[F]  # (m', 3, 3): read once, for the normals and the centroids
    p0 = corners[:, 0].T  # (3, m') views: coordinate-major, as face_normals_areas reads them
    normals, areas = _normals_areas(_cross(corners[:, 1].T - p0, corners[:, 2].T - p0))
    # the face areas at each curve vertex (incidence ⊙ areas), in the incidence's order
    weights = incidence.data.astype(areas.dtype, copy=False) * areas[incidence.indices]
    W = sp.csr_matrix((weights, incidence.indices, incidence.indptr), shape=incidence.shape)
    n = unit(W @ normals)
    if radius is not None and radius > 0:
        n = _quadric_normals(V, P, n, T, radius)
    h = unit(_cross(n.T, T.T).T)  # C-ordered, as np.cross returns it (einsum sums by layout)
    # sign: the inward direction points towards the faces at the vertex. The faces'
    # centroids have their corners summed in order (as corners.mean(axis=1)), the rows of
    # W are summed as W.sum(axis=1) adds them (np.add.reduceat over each row's entries)
    centroids = (corners[:, 0] + corners[:, 1] + corners[:, 2]) / 3.0
    rows = np.flatnonzero(np.diff(incidence.indptr))
    total = np.zeros((len(P), 1), dtype=weights.dtype)
    total[rows, 0] = np.add.reduceat(weights, incidence.indptr[rows])
    centroid_offset = (W @ centroids) / np.maximum(total, 1e-300) - P
    flip = np.einsum("ij,ij->i", h, centroid_offset) < 0
    h[flip] *= -1.0
    return SeamFrames(normal=n, tangent=T, inward=h)


def seam_frames(
    V: np.ndarray,
    F: np.ndarray,
    curve: np.ndarray,
    closed: bool,
    *,
    radius: float | None = None,
    curve_points: np.ndarray | None = None,
) -> SeamFrames:
    """Normals, curve tangents and inward directions along a boundary curve.

    ``curve_frames(V, curve_faces(F, curve, len(V), P, closed, radius=radius))``
    with ``P`` the curve points: only the faces at the curve enter the
    frames, kept in their order so that every sum runs as over all faces.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    curve : ndarray of int64, shape (k,)
        Ordered boundary vertices.
    closed : bool
    radius : float, optional
        Smoothing radius. ``None`` gives the one-ring estimate.
    curve_points : ndarray, shape (k, 3), optional
        Positions to use for the curve tangents (default ``V[curve]``).

    Returns
    -------
    SeamFrames
    """
    P = V[curve] if curve_points is None else curve_points
    return curve_frames(V, curve_faces(F, curve, len(V), P, closed, radius=radius))


def _quadric_normals(
    V: np.ndarray, P: np.ndarray, n0: np.ndarray, T: np.ndarray, radius: float
) -> np.ndarray:
    """Normals at boundary points from a weighted quadric fit of the surface around each.

    The surface near ``P[i]`` is fitted as a height function
    ``z = a x² + b xy + c y² + d x + e y + f`` over the frame (``T``,
    ``n0 × T``, ``n0``) from the vertices within ``radius``; the normal is
    that of the fit at ``P[i]``. Unlike a plain average of one-sided face
    normals it is not biased by curvature at a boundary, and it averages
    out noise. Points with fewer than 10 neighbours keep ``n0``.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    P : ndarray, shape (k, 3)
    n0, T : ndarray, shape (k, 3)
        Reference normals and curve tangents.
    radius : float

    Returns
    -------
    ndarray, shape (k, 3)
    """
    lo, hi = P.min(axis=0) - radius, P.max(axis=0) + radius
    near = np.flatnonzero(((V >= lo) & (V <= hi)).all(axis=1))
    from scipy.spatial import cKDTree  # here: scipy.spatial costs start-up time

    hits = cKDTree(V[near]).query_ball_point(P, radius)
    counts = np.array([len(h) for h in hits])
    M = int(counts.max()) if counts.size else 0
    if M < 10:
        return n0
    idx = np.zeros((len(P), M), dtype=np.int64)
    valid = np.arange(M)[None, :] < counts[:, None]
    idx[valid] = near[np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])]
    B = unit(np.cross(n0, T))
    A = unit(np.cross(B, n0))
    D = V[idx] - P[:, None, :]
    x = np.einsum("kmj,kj->km", D, A)
    y = np.einsum("kmj,kj->km", D, B)
    z = np.einsum("kmj,kj->km", D, n0)
    w = np.where(valid, np.clip(1.0 - (x**2 + y**2) / radius**2, 0.0, None) + 1e-3, 0.0)
    X = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=2)
    scale = np.array([radius**2, radius**2, radius**2, radius, radius, 1.0])
    X = X / scale
    AtA = np.einsum("km,kmi,kmj->kij", w, X, X) + 1e-9 * np.eye(6)
    Atz = np.einsum("km,kmi,km->ki", w, X, z)
    coef = np.linalg.solve(AtA, Atz[..., None])[..., 0] / scale
    n = unit(n0 - coef[:, 3:4] * A - coef[:, 4:5] * B)
    ok = counts >= 10
    return np.where(ok[:, None], n, n0)
