"""Combinatorics of triangle arrays: edges, edge-face counts, vertex fans, components, orientation.

The one place that decides manifoldness: :mod:`igljoin.validate`,
:mod:`igljoin.clean` and :mod:`igljoin.weld` call these functions and keep
only their messages. Everything here reads index arrays only (no
coordinates, except :func:`shared_rows`) and returns plain arrays.

Conventions: ``F`` is ``(m, 3)`` int64 with entries in ``[0, n)``. Half-edge
``3 f + i`` runs from vertex ``F[f, i]`` to ``F[f, (i + 1) % 3]``; an
undirected edge ``{a, b}`` has the key ``min(a, b) * n + max(a, b)``
(``n ** 2`` fits in an int64 for any ``n`` below 3e9).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = [
    "components",
    "edges",
    "fan_counts",
    "half_edges",
    "orientable",
    "repeated_directed_edges",
    "repeated_directed_pairs",
    "repeated_rows",
    "row_counts",
    "runs",
    "shared_rows",
    "vertex_manifold",
]


def runs(skey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def row_counts(A: np.ndarray, n: int) -> np.ndarray:
    """How often each distinct row of an index array occurs.

    Equal to ``np.unique(A, axis=0, return_counts=True)[1]`` but sorts one
    int64 key per row (the row's base-``n`` digits) instead of structured
    rows, about ten times faster; falls back to that call when ``n ** w``
    does not fit in an int64.

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
    return runs(key)[1]


def half_edges(F: np.ndarray, n: int):
    """The half-edges of a triangle array, sorted by undirected edge.

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
        Half-edges sorted by key (stable).
    skey : ndarray of int64, shape (3 m,)
        Their sorted keys.
    """
    m = len(F)
    src = np.asarray(F, dtype=np.int64).reshape(-1)
    ahead = (np.arange(3 * m, dtype=np.int64).reshape(m, 3)[:, [1, 2, 0]]).reshape(-1)
    dst = src[ahead]
    key = np.minimum(src, dst) * n + np.maximum(src, dst)
    order = np.argsort(key, kind="stable")
    return src, ahead, order, key[order]


def edges(F: np.ndarray, n: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges, the edge of each face side, and the faces at each edge.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    n : int, optional
        Number of vertices (default ``F.max() + 1``).

    Returns
    -------
    E : ndarray of int64, shape (e, 2)
        Distinct edges ``(a, b)`` with ``a < b`` (``a == b`` for the side of
        a face repeating a vertex), in lexicographic order.
    side_edge : ndarray of int64, shape (3 m,)
        Row of ``E`` of each face side, sides ordered ``(0, 1)`` of every
        face, then ``(1, 2)``, then ``(2, 0)`` (as
        ``np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])``).
    count : ndarray of int64, shape (e,)
        Face sides on each edge: 1 on the boundary, 2 inside, more where
        the surface is not edge-manifold.

    Examples
    --------
    >>> E, _, count = edges(np.array([[0, 1, 2], [2, 1, 3]]))
    >>> E.tolist(), count.tolist()
    ([[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]], [1, 1, 2, 1, 1])
    """
    F = np.asarray(F, dtype=np.int64)
    if not len(F):
        empty = np.zeros(0, dtype=np.int64)
        return np.zeros((0, 2), dtype=np.int64), empty, empty
    n = int(F.max()) + 1 if n is None else int(n)
    FT = np.ascontiguousarray(F.T)
    a = np.concatenate([FT[0], FT[1], FT[2]])
    b = np.concatenate([FT[1], FT[2], FT[0]])
    key = np.minimum(a, b) * n + np.maximum(a, b)
    uniq, side_edge, count = np.unique(key, return_inverse=True, return_counts=True)
    E = np.stack(np.divmod(uniq, n), axis=1)
    return E, side_edge.reshape(-1), count


def _corner_fans(F: np.ndarray, n: int, half=None) -> np.ndarray:
    """Fan label of each face corner, shape (3 m,): corners of one fan share a label.

    Two corners of a vertex are in one fan when their faces share an
    (undirected) edge at that vertex; found as the connected components of
    a graph whose nodes are the corners, the corners at both ends of each
    shared edge joined.
    """
    m = len(F)
    src, ahead, order, skey = half_edges(F, n) if half is None else half
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
    return connected_components(graph, directed=False)[1]


def vertex_manifold(F: np.ndarray, n: int, half=None) -> np.ndarray:
    """Whether the faces around each vertex form one edge-connected fan.

    Two faces containing a vertex ``v`` are neighbours around ``v`` when
    they share an (undirected) edge; ``v`` is manifold when its faces are all
    connected that way. This is what ``igl.is_vertex_manifold`` computes
    (unreferenced vertices are reported non-manifold, and so are vertices
    past ``F.max()``).

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
        Triangles, entries in ``[0, n)``.
    n : int
        Number of vertices.
    half : tuple, optional
        ``half_edges(F, n)`` when the caller has it already.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for vertices used by a face whose faces form a single fan.

    Notes
    -----
    Kept instead of ``igl.is_vertex_manifold`` for its speed, measured on
    this machine (medians): 0.6-1.2 ms against 5.2-10.5 ms on the paper
    samples' hosts and guests (2,400-4,800 faces), 6.7-7.6 ms against
    62-82 ms at three times their resolution (18,000-21,000 faces). Every
    join checks host and guest (:func:`igljoin.validate.check_surface`), so
    libigl would add about 9 ms to a paper-sample join of about 150 ms (6 %)
    and 130 ms to the 1.2 s join at three times the resolution (10 %).

    Examples
    --------
    >>> bowtie = np.array([[0, 1, 2], [0, 3, 4]])  # two triangles touching at vertex 0
    >>> vertex_manifold(bowtie, 5).tolist()
    [False, True, True, True, True]
    """
    F = np.asarray(F, dtype=np.int64)
    src = F.reshape(-1)
    label = _corner_fans(F, n, half)
    # compare each corner's fan with that of one corner of the same vertex
    used = np.zeros(n, dtype=bool)
    used[src] = True
    some = np.zeros(n, dtype=label.dtype)
    some[src] = label
    split = np.zeros(n, dtype=bool)
    split[src[label != some[src]]] = True
    return used & ~split


def fan_counts(F: np.ndarray, n: int) -> np.ndarray:
    """Number of face fans of faces ``F`` (m, 3) around each of ``n`` vertices, shape (n,).

    0 for an unused vertex, 1 where :func:`vertex_manifold` holds, more
    where several fans meet at the vertex (a bow-tie has 2); int64.
    """
    F = np.asarray(F, dtype=np.int64)
    if not len(F):
        return np.zeros(n, dtype=np.int64)
    src = F.reshape(-1)
    label = _corner_fans(F, n).astype(np.int64)
    key = np.unique(src * (3 * len(F)) + label)
    return np.bincount(key // (3 * len(F)), minlength=n)


def components(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of the faces (faces sharing a vertex are connected).

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    n : int

    Returns
    -------
    label : ndarray of int64, shape (m,)
        Component of each face, numbered ``0 .. c − 1`` in order of their
        first face.
    size : ndarray of int64, shape (c,)
        Faces per component.
    """
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    rows = np.repeat(np.arange(m), 3)
    graph = coo_matrix((np.ones(3 * m), (rows, m + F.reshape(-1))), shape=(m + n, m + n))
    _, label = connected_components(graph, directed=False)
    _, face_label = np.unique(label[:m], return_inverse=True)
    face_label = face_label.reshape(-1).astype(np.int64)
    return face_label, np.bincount(face_label).astype(np.int64)


def repeated_directed_edges(F: np.ndarray, n: int | None = None) -> int:
    """How many directed edges ``a -> b`` of faces ``F`` (m, 3) more than one face side traverses.

    On an edge-manifold surface each joins two neighbours of opposite
    orientation. ``n`` is the number of vertices (default ``F.max() + 1``).
    """
    F = np.asarray(F, dtype=np.int64)
    if not len(F):
        return 0
    n = int(F.max()) + 1 if n is None else int(n)
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return int((row_counts(directed, n) > 1).sum())


def repeated_directed_pairs(half, pairs: np.ndarray) -> int:
    """:func:`repeated_directed_edges` of a surface whose edges have at most two face sides.

    Read from its half-edges sorted by undirected edge (``half_edges(F, n)``):
    where no undirected edge has more than two sides and no face repeats a
    vertex, a directed edge is traversed twice exactly where the two sides
    of an edge start at the same vertex; no second sort is needed.

    Parameters
    ----------
    half : tuple
        ``half_edges(F, n)``.
    pairs : ndarray of int64
        Where each run of two equal keys starts in the sorted half-edges
        (``start[count == 2]`` of :func:`runs` of their keys).

    Returns
    -------
    int
    """
    src, _, order, _ = half
    return int(np.count_nonzero(src[order[pairs]] == src[order[pairs + 1]]))


def orientable(F: np.ndarray) -> bool:
    """Whether the edge-manifold surface ``F`` (m, 3) can be oriented consistently.

    libigl's ``bfs_orient`` flips faces to agree with their neighbours; if
    some edge is still traversed twice in the same direction afterwards, no
    orientation exists (a Möbius strip).
    """
    import igl  # here, not at the top: libigl costs start-up time (igljoin info)

    FF, _ = igl.bfs_orient(np.ascontiguousarray(F, dtype=np.int64))
    return repeated_directed_edges(np.asarray(FF, dtype=np.int64)) == 0


def shared_rows(P: np.ndarray) -> np.ndarray:
    """Flag the rows of ``P`` whose coordinates equal those of another row.

    Rows compare with float ``==`` per coordinate (so ``-0.0`` equals
    ``0.0``), as ``np.unique(P, axis=0)`` compares them: duplicate vertex
    positions.

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


def repeated_rows(P: np.ndarray) -> int:
    """Rows of ``P`` (k, 3) equal to an earlier row: ``k − len(np.unique(P, axis=0))``."""
    if not len(P):
        return 0
    S = P[np.lexsort(P.T)]
    return int((S[1:] == S[:-1]).all(axis=1).sum())
