"""Topological checks a mesh must pass before it is joined."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .errors import MeshError, SolveError
from .mesh import Mesh

__all__ = [
    "MAX_COORDINATE",
    "MAX_SEAM_LENGTH_RATIO",
    "MIN_EDGE_DIGITS",
    "check_coordinates",
    "check_seam_scales",
    "check_surface",
    "check_guest_reaches_seam",
    "relative_area_floor",
    "vertex_manifold",
]

#: Faces whose area is below this fraction of the mean face area count as zero-area.
relative_area_floor = 1e-12

#: Largest coordinate magnitude accepted. The join squares lengths and multiplies
#: areas (fourth powers of coordinates) in float64, which overflows near 1e308:
#: at 1e77 every face area already comes out as zero. 1e50 leaves a wide margin
#: and is far beyond any unit (a metre in nanometres is 1e9).
MAX_COORDINATE = 1e50
#: Fewest significant decimal digits of an edge length that the coordinates must
#: keep: with |x| = 1e15 and unit edges float64 resolves 0.1 of an edge, and the
#: seam gap came out at 29 % of an edge. 4 digits keep rounding below 1e-4 edges.
MIN_EDGE_DIGITS = 4
#: Largest ratio of the two seam curves' lengths: a guest whose seam is 4 times
#: longer (or shorter) than the host's must be squeezed (stretched) 4-fold along
#: the whole seam, the sign of a unit mismatch (mm vs cm is 10x) rather than of a
#: graft that fits; the paper's longer/shorter samples differ by far less.
MAX_SEAM_LENGTH_RATIO = 4.0


def check_coordinates(mesh: Mesh, role: str) -> None:
    """Refuse coordinates too large for float64 or too large for the mesh's edge lengths.

    Parameters
    ----------
    mesh : Mesh
    role : str
        Name used in messages.

    Raises
    ------
    MeshError
        If a coordinate exceeds :data:`MAX_COORDINATE` in magnitude, or the
        largest magnitude leaves fewer than :data:`MIN_EDGE_DIGITS` significant
        digits of the median edge length (e.g. a mesh placed at 1e15).
    """
    if mesh.n_vertices == 0 or mesh.n_faces == 0:
        return
    mag = float(np.abs(mesh.V).max())
    if mag > MAX_COORDINATE:
        raise MeshError(
            f"{role}: coordinates reach {mag:.3g}, beyond the {MAX_COORDINATE:.0e} igljoin "
            "accepts: areas and squared lengths of such coordinates overflow float64; rescale "
            "the mesh to its real units (e.g. millimetres)"
        )
    F = mesh.F
    e = np.linalg.norm(mesh.V[F[:, [1, 2, 0]]] - mesh.V[F], axis=2).reshape(-1)
    edge = float(np.median(e))
    resolution = mag * np.finfo(np.float64).eps
    if edge > 0 and resolution > edge * 10.0**-MIN_EDGE_DIGITS:
        digits = max(0.0, np.log10(edge / resolution)) if resolution > 0 else 16.0
        raise MeshError(
            f"{role}: coordinates of magnitude {mag:.3g} keep only {digits:.1f} significant "
            f"digits of its median edge length {edge:.3g} (float64 has 16 in all); results "
            f"would be rounding noise. Move host and guest by the same offset near the origin "
            "(subtract the host's centroid from both) and join again"
        )


def _curve_length(V: np.ndarray, idx: np.ndarray, closed: bool) -> float:
    P = V[np.asarray(idx)]
    seg = (np.roll(P, -1, axis=0) - P) if closed else np.diff(P, axis=0)
    return float(np.linalg.norm(seg, axis=1).sum())


def check_seam_scales(host_V: np.ndarray, guest_V: np.ndarray, seams) -> None:
    """Refuse seams whose host and guest curves differ in length by a unit-mismatch factor.

    Parameters
    ----------
    host_V : ndarray, shape (n_h, 3)
    guest_V : ndarray, shape (n_g, 3)
    seams : iterable
        Objects with ``host_curve`` and ``guest_curve``, each having
        ``indices`` (ndarray of int) and ``closed`` (bool).

    Raises
    ------
    MeshError
        If a guest curve is more than :data:`MAX_SEAM_LENGTH_RATIO` times
        longer or shorter than its host curve.
    """
    for k, s in enumerate(seams):
        hc, gc = s.host_curve, s.guest_curve
        lh = _curve_length(host_V, hc.indices, bool(hc.closed))
        lg = _curve_length(guest_V, gc.indices, bool(gc.closed))
        if lh <= 0 or lg <= 0:
            continue
        ratio = lg / lh
        if ratio > MAX_SEAM_LENGTH_RATIO or ratio < 1.0 / MAX_SEAM_LENGTH_RATIO:
            which = "" if k == 0 else f" (seam {k})"
            raise MeshError(
                f"the guest curve{which} is {ratio:.3g} times as long as the host curve "
                f"({lg:.4g} against {lh:.4g}); beyond a factor {MAX_SEAM_LENGTH_RATIO:g} the "
                "guest cannot fit without a gross squeeze or stretch: check that both meshes "
                "use the same units (mm vs cm is a factor 10) and that the right curves are "
                "selected"
            )


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
    check_coordinates(mesh, role)
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
        if not orientable(F):
            raise MeshError(
                f"{role}: the surface is non-orientable (a Möbius-like twist: no choice of face "
                "orientations is consistent), so it has no inside and outside to join; "
                "igljoin clean cannot fix this: remodel the surface or cut it along the twist"
            )
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


def orientable(F: np.ndarray) -> bool:
    """Whether the edge-manifold surface ``F`` can be oriented consistently.

    libigl's ``bfs_orient`` flips faces to agree with their neighbours; if
    some edge is still traversed twice in the same direction afterwards, no
    orientation exists (a Möbius strip).
    """
    import igl  # here, not at the top: libigl costs start-up time (igljoin info)

    FF, _ = igl.bfs_orient(np.ascontiguousarray(F, dtype=np.int64))
    FF = np.asarray(FF)
    n = int(F.max()) + 1
    directed = np.concatenate([FF[:, [0, 1]], FF[:, [1, 2]], FF[:, [2, 0]]])
    return not (_row_counts(directed, n) > 1).any()


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
