"""Topological checks a mesh must pass before it is joined."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .errors import MeshError, SolveError
from .mesh import Mesh

__all__ = [
    "check_surface",
    "check_guest_reaches_seam",
    "relative_area_floor",
    "vertex_manifold",
]

#: Faces whose area is below this fraction of the mean face area count as zero-area.
relative_area_floor = 1e-12


def _first(idx: np.ndarray, k: int = 5) -> str:
    return str(np.asarray(idx)[:k].tolist())


def _runs(skey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of equal values in a sorted array.

    Parameters
    ----------
    skey : ndarray of int64, shape (k,)
        Sorted values.

    Returns
    -------
    start : ndarray of int64, shape (u,)
        Index of the first element of each run.
    count : ndarray of int64, shape (u,)
        Length of each run.
    """
    start = np.flatnonzero(np.concatenate([[True], skey[1:] != skey[:-1]]))
    return start, np.diff(np.append(start, skey.size))


def _row_counts(A: np.ndarray, n: int) -> np.ndarray:
    """How often each distinct row of an index array occurs.

    Equal to ``np.unique(A, axis=0, return_counts=True)[1]`` but sorts one
    int64 key per row (the row's base-``n`` digits) instead of structured
    rows; falls back to that call when ``n ** w`` does not fit in an int64.

    Parameters
    ----------
    A : ndarray of int64, shape (k, w)
        Entries in ``[0, n)``.
    n : int
        Exclusive upper bound of the entries.

    Returns
    -------
    ndarray of int64, shape (u,)
        Occurrences of each distinct row, rows in lexicographic order.
    """
    w = A.shape[1]
    if n**w > np.iinfo(np.int64).max:
        return np.unique(A, axis=0, return_counts=True)[1]
    key = A[:, 0].astype(np.int64)
    for j in range(1, w):
        key = key * n + A[:, j]
    key.sort()
    return _runs(key)[1]


def _half_edges(F: np.ndarray, n: int):
    """The half-edges of a triangle array, sorted by undirected edge.

    Half-edge ``3 f + i`` runs from corner ``3 f + i`` (vertex ``F[f, i]``) to
    corner ``ahead[3 f + i]`` (vertex ``F[f, (i + 1) % 3]``). Its undirected
    edge ``{a, b}`` has the key ``min(a, b) * n + max(a, b)`` (``n ** 2`` fits
    in an int64 for any ``n`` below 3e9).

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
        Entries in ``[0, n)``.
    n : int

    Returns
    -------
    src : ndarray of int64, shape (3 m,)
        Start vertex of each half-edge (``F.reshape(-1)``).
    ahead : ndarray of int64, shape (3 m,)
        Corner at the end of each half-edge.
    order : ndarray of int64, shape (3 m,)
        Half-edges sorted by key.
    skey : ndarray of int64, shape (3 m,)
        Their sorted keys.
    """
    m = len(F)
    src = F.reshape(-1)
    ahead = (np.arange(3 * m, dtype=np.int64).reshape(m, 3)[:, [1, 2, 0]]).reshape(-1)
    dst = src[ahead]
    key = np.minimum(src, dst) * n + np.maximum(src, dst)
    order = np.argsort(key, kind="stable")
    return src, ahead, order, key[order]


def _shared_rows(P: np.ndarray) -> np.ndarray:
    """Flag the rows of ``P`` whose coordinates equal those of another row.

    Rows compare with float ``==`` per coordinate (so ``-0.0`` equals ``0.0``),
    as ``np.unique(P, axis=0)`` compares them.

    Parameters
    ----------
    P : ndarray of float64, shape (k, 3)
        Finite coordinates.

    Returns
    -------
    ndarray of bool, shape (k,)
    """
    k = len(P)
    order = np.lexsort(P.T)
    S = P[order]
    same = (S[1:] == S[:-1]).all(axis=1)
    flag = np.zeros(k, dtype=bool)
    flag[1:] |= same
    flag[:-1] |= same
    out = np.empty(k, dtype=bool)
    out[order] = flag
    return out


def vertex_manifold(F: np.ndarray, n: int) -> np.ndarray:
    """Whether the faces around each vertex form one edge-connected fan.

    Two faces containing a vertex ``v`` are neighbours around ``v`` when they
    share an (undirected) edge; ``v`` is manifold when its faces are all
    connected that way. This is what ``igl.is_vertex_manifold`` computes
    (unreferenced vertices are reported non-manifold), found here as the
    connected components of a graph whose nodes are the face corners: the
    corners of two faces at both ends of each shared edge are joined.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
        Triangles, entries in ``[0, n)``.
    n : int
        Number of vertices.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for vertices used by a face whose faces form a single fan.
    """
    F = np.asarray(F, dtype=np.int64)
    return _fans_connected(len(F), n, *_half_edges(F, n))


def _fans_connected(m, n, src, ahead, order, skey) -> np.ndarray:
    """:func:`vertex_manifold` of ``m`` faces from their half-edges (see :func:`_half_edges`)."""
    run = np.flatnonzero(skey[1:] == skey[:-1])
    h1, h2 = order[run], order[run + 1]  # consecutive half-edges on one undirected edge
    aligned = src[h1] == src[h2]
    tail2 = np.where(aligned, h2, ahead[h2])
    head2 = np.where(aligned, ahead[h2], h2)
    # a face holding a vertex twice has a second edge between the same two vertices,
    # so its two corners of that vertex are joined here as well
    rows = np.concatenate([h1, ahead[h1]])
    cols = np.concatenate([tail2, head2])
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(3 * m, 3 * m))
    _, label = connected_components(graph, directed=False)
    # compare each corner's component with that of one corner of the same vertex
    used = np.zeros(n, dtype=bool)
    used[src] = True
    some = np.zeros(n, dtype=label.dtype)
    some[src] = label
    split = np.zeros(n, dtype=bool)
    split[src[label != some[src]]] = True
    return used & ~split


def check_surface(mesh: Mesh, role: str) -> None:
    """Raise :class:`MeshError` unless ``mesh`` is a clean manifold triangle surface.

    Checks faces repeating a vertex, zero-area faces, duplicate faces,
    non-manifold edges and vertices and (for the guest) unreferenced vertices.

    Parameters
    ----------
    mesh : Mesh
    role : {"host", "guest"}
    """
    F = mesh.F
    fix = "repair it with igljoin.clean(mesh) (or `igljoin clean IN -o OUT`)"
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    if rep.any():
        idx = np.flatnonzero(rep)
        raise MeshError(
            f"{role}: {idx.size} faces repeat a vertex (degenerate; first {_first(idx)}); {fix}"
        )
    import igl  # here, not at the top: libigl costs start-up time (igljoin info)

    area = igl.doublearea(mesh.V, F)
    floor = relative_area_floor * max(float(area.mean()), 1e-300)
    zero = area <= floor
    if zero.any():
        idx = np.flatnonzero(zero)
        raise MeshError(f"{role}: {idx.size} faces have zero area (first {_first(idx)}); {fix}")
    n = mesh.n_vertices
    count = _row_counts(np.sort(F, axis=1), n)
    if (count > 1).any():
        raise MeshError(
            f"{role}: {int((count > 1).sum())} faces are duplicated (same three vertices); {fix}"
        )
    half = _half_edges(F, n)
    src, ahead, _, skey = half
    start, cnt = _runs(skey)
    if (cnt > 2).any():
        bad = np.stack(np.divmod(skey[start[cnt > 2]], n), axis=1)
        raise MeshError(
            f"{role}: {len(bad)} edges are shared by more than two faces (non-manifold; first "
            f"{bad[:3].tolist()}); {fix}"
        )
    dcount = _row_counts(np.stack([src, src[ahead]], axis=1), n)
    if (dcount > 1).any():
        raise MeshError(
            f"{role}: {int((dcount > 1).sum())} edges are traversed twice in the same direction "
            f"(faces inconsistently oriented); {fix} — it orients faces consistently"
        )
    used = np.zeros(n, dtype=bool)
    used[src] = True
    if role == "guest":
        shared = _shared_rows(mesh.V[used])
        if shared.any():
            dup = np.flatnonzero(used)[shared]
            raise MeshError(
                f"guest: {dup.size} vertices share their position with another vertex "
                f"(duplicates, first {_first(dup)}); they split the surface into pieces — {fix}"
            )
    vm = _fans_connected(len(F), n, *half)
    bad_v = np.flatnonzero(~vm & used)
    if bad_v.size:
        raise MeshError(
            f"{role}: {bad_v.size} vertices are non-manifold (their faces form separate fans; "
            f"first {_first(bad_v)}); {fix}"
        )
    if role == "guest" and not used.all():
        idx = np.flatnonzero(~used)
        raise MeshError(
            f"guest: {idx.size} vertices are not used by any face (unreferenced; first "
            f"{_first(idx)}); they cannot be deformed — {fix}"
        )


def check_guest_reaches_seam(F: np.ndarray, n: int, seam: np.ndarray) -> None:
    """Raise :class:`SolveError` if a guest component has no seam vertex or nothing is free.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
        Refined guest faces.
    n : int
        Number of refined guest vertices.
    seam : ndarray of int64, shape (s,)
    """
    if np.unique(seam).size >= n:
        raise SolveError(
            "guest: every vertex lies on the seam, so there is nothing to deform (no free "
            "vertex); the guest needs interior vertices — refine it with "
            "igljoin.resample(guest, target_edge) (or resample = true in join.toml) or join a "
            "larger piece"
        )
    import igl

    comp = np.asarray(igl.vertex_components(F), dtype=np.int64)
    touched = np.unique(comp[seam])
    loose = np.setdiff1d(np.unique(comp), touched)
    if loose.size:
        sizes = [int((comp == c).sum()) for c in loose[:5]]
        raise SolveError(
            f"guest: {loose.size} connected components do not touch the seam (vertex counts "
            f"{sizes}); nothing holds them in place — remove them or join each with its own "
            "seam"
        )
