"""Join-quality measures: seam gap, crease angle, deformation maps, folds, intersections.

Every function takes plain arrays and returns new arrays or plain dicts;
``docs/results.md`` lists each measure with its definition and units.

Crease angle
    At a host curve vertex ``q`` (hit exactly by a guest seam vertex), take
    the curve tangent ``T``, the host's one-ring normal and the deformed
    guest's one-ring normal there. Each surface's cross-seam direction is its
    tangent perpendicular to ``T`` pointing into that surface (host ``h``,
    guest ``g``). The crease is the angle between ``g`` and ``−h``, the host
    surface continued across the boundary: 0° for a smooth join, 180° for a
    guest folded back onto the host.

Host dihedral angle
    The angle between the normals of two host faces sharing an edge, for the
    host faces within two rings of the host curve: the crease the rigid host
    itself has there (its discretisation and noise), so that a seam crease
    can be judged against it.

Deformation maps
    Per face: area ratio (deformed / rest). Per edge: strain ``(ℓ′ − ℓ)/ℓ``.
    Per vertex: strain (mean of the incident edges' strains) and non-rigid
    displacement (distance to the rest guest rigidly aligned onto the
    deformed one by a least-squares proper rotation and translation).

Self-intersections
    Pairs of faces of the welded mesh that intersect other than along shared
    edges or vertices, found by CGAL's exact predicates through
    ``igl.copyleft.cgal.remesh_self_intersections(detect_only=True)``; only
    the faces near the seam (:func:`ring_band`) are tested, which keeps it
    cheap enough to run on every join.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

import numpy as np
from scipy.spatial import cKDTree

from .correspond import rigid_fit
from .errors import OptionsError
from .frames import face_areas, face_normals_areas, seam_frames

__all__ = [
    "area_ratio",
    "edge_strain",
    "vertex_strain",
    "nonrigid_displacement",
    "crease_angles",
    "edge_dihedral_angles",
    "host_dihedral_angles",
    "ring_band",
    "self_intersections",
    "seam_gap",
    "folded_pairs",
    "summary",
    "point_polyline_distance",
]

#: Default number of vertex rings around the seam searched for self-intersections.
SELF_INTERSECTION_RINGS = 3

#: Default number of rings around the host curve whose dihedral angles are measured.
HOST_DIHEDRAL_RINGS = 2


#: Values derived from a mesh's arrays alone, per vertex array: ``id(V)`` ->
#: (weak reference to ``V``, private copies of ``V`` and ``F``, values), oldest first.
_MEMO: OrderedDict[int, tuple] = OrderedDict()
#: Meshes whose derived values are kept at once (the oldest is dropped first).
_MEMO_MESHES = 8
#: Serialises look-ups and insertions (joins may run in threads).
_MEMO_LOCK = threading.RLock()


def _mesh_memo(V: np.ndarray, F: np.ndarray) -> dict:
    """A dict of values computed from ``(V, F)`` alone, kept across calls.

    The entry is found by the identity of ``V`` and used only while ``V``
    and ``F`` still hold exactly the values it was made for (compared with
    private copies on every call): changed or different arrays get a fresh,
    empty dict, so a value read from it is never stale. The entry goes when
    ``V`` is garbage collected. Meant for the rigid host, whose arrays are
    the same objects on every join with that ``Mesh``.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int, shape (m, 3)

    Returns
    -------
    dict
        Keys name the value and the other arguments it depends on.
    """
    key = id(V)
    with _MEMO_LOCK:
        entry = _MEMO.get(key)
        if entry is not None:
            ref, Vc, Fc, values = entry
            if (
                ref() is V
                and Vc.shape == np.shape(V)
                and Fc.shape == np.shape(F)
                and np.array_equal(Vc, V)
                and np.array_equal(Fc, F)
            ):
                return values
        try:
            ref = weakref.ref(V, lambda _, key=key: _MEMO.pop(key, None))
        except TypeError:  # not weak-referenceable (not an ndarray): nothing kept
            return {}
        while len(_MEMO) >= _MEMO_MESHES:
            try:
                _MEMO.popitem(last=False)
            except KeyError:  # emptied meanwhile by arrays going away
                break
        values: dict = {}
        _MEMO[key] = (ref, np.array(V, copy=True), np.array(F, copy=True), values)
        return values


def area_ratio(V0: np.ndarray, V1: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Deformed over rest area of each face (the paper's deformation display).

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
        Rest and deformed positions.
    F : ndarray of int64, shape (m, 3)

    Returns
    -------
    ndarray, shape (m,)
        1 where a face kept its area, > 1 stretched, < 1 shrunk.
    """
    a0 = face_areas(V0, F)
    a1 = face_areas(V1, F)
    return a1 / np.where(a0 > 0, a0, np.nan)


def edge_strain(V0: np.ndarray, V1: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Relative length change ``(ℓ′ − ℓ)/ℓ`` of each edge ``E`` (shape (e, 2)) -> (e,)."""
    E = np.asarray(E)
    l0 = _edge_lengths(V0, E)
    l1 = _edge_lengths(V1, E)
    return (l1 - l0) / np.where(l0 > 0, l0, np.nan)


def _row_norms(D: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(D.T, axis=1)`` of a coordinate-major array ``D``, shape (3, e) -> (e,).

    The squares are summed left to right, as that call sums them, so the
    values agree to the last bit; the rows of ``D`` are contiguous, which
    makes it several times faster than the row-wise call.
    """
    if not np.issubdtype(D.dtype, np.inexact):
        D = D.astype(np.float64)
    sq = D * D
    return np.sqrt((sq[0] + sq[1]) + sq[2])


def _edge_lengths(V: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Length of each edge ``V[E[:, 0]] − V[E[:, 1]]``, shape (e,), for ``E`` of shape (e, 2)."""
    VT = np.ascontiguousarray(np.asarray(V).T)  # (3, n)
    ET = np.ascontiguousarray(E.T)  # (2, e)
    return _row_norms(np.take(VT, ET[0], axis=1) - np.take(VT, ET[1], axis=1))


def vertex_strain(E: np.ndarray, strain: np.ndarray, n: int) -> np.ndarray:
    """Per-vertex strain: the mean strain of the edges incident to each vertex.

    Parameters
    ----------
    E : ndarray of int64, shape (e, 2)
        Undirected edges, each listed once.
    strain : ndarray, shape (e,)
        Per-edge strain (:func:`edge_strain`); non-finite values are ignored.
    n : int
        Number of vertices.

    Returns
    -------
    ndarray, shape (n,)
        Signed mean relative length change of the incident edges (0 = no
        change, 0.1 = edges 10 % longer on average); NaN for a vertex without
        a finite incident edge.

    Examples
    --------
    >>> import numpy as np
    >>> vertex_strain(np.array([[0, 1], [1, 2]]), np.array([0.2, 0.0]), 3)
    array([0.2, 0.1, 0. ])
    """
    E = np.asarray(E, dtype=np.int64).reshape(-1, 2)
    s = np.asarray(strain, dtype=np.float64)
    ok = np.isfinite(s)
    ends = E[ok].reshape(-1)
    total = np.bincount(ends, weights=np.repeat(s[ok], 2), minlength=n)
    count = np.bincount(ends, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def nonrigid_displacement(V0: np.ndarray, V1: np.ndarray) -> np.ndarray:
    """Distance of each deformed vertex from the rigidly aligned rest vertex.

    The rest positions are first moved onto the deformed ones by the proper
    rotation and translation that minimise the summed squared distances
    (Kabsch); what remains is the deformation, not the placement.

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
        Rest and deformed positions.

    Returns
    -------
    ndarray, shape (n,)
        In the mesh's length unit (mm for the phantoms); 0 for a rigid motion.
    """
    V0 = np.asarray(V0, dtype=np.float64)
    V1 = np.asarray(V1, dtype=np.float64)
    R, t = rigid_fit(V0, V1)
    return _row_norms(np.ascontiguousarray((V1 - (V0 @ R.T + t)).T))


def crease_angles(
    Vh: np.ndarray,
    Fh: np.ndarray,
    host_curve: np.ndarray,
    Vg: np.ndarray,
    Fg: np.ndarray,
    guest_at_host: np.ndarray,
    closed: bool,
) -> np.ndarray:
    """Crease angle in degrees at each host curve vertex.

    Parameters
    ----------
    Vh : ndarray, shape (n_h, 3)
    Fh : ndarray of int64, shape (m_h, 3)
    host_curve : ndarray of int64, shape (k,)
        Ordered host curve vertices.
    Vg : ndarray, shape (n_g, 3)
    Fg : ndarray of int64, shape (m_g, 3)
        Guest surface (deformed, or in place for an uncut reference).
    guest_at_host : ndarray of int64, shape (k,)
        Guest vertex lying on each host curve vertex.
    closed : bool

    Returns
    -------
    ndarray, shape (k,)
    """
    host_curve = np.asarray(host_curve, dtype=np.int64)
    memo = _mesh_memo(Vh, Fh)
    key = ("seam_frames", host_curve.tobytes(), bool(closed))
    if key not in memo:
        inward = seam_frames(Vh, Fh, host_curve, closed).inward
        inward.flags.writeable = False
        memo[key] = inward
    host_inward = memo[key]
    guest = seam_frames(Vg, Fg, guest_at_host, closed, curve_points=Vh[host_curve])
    cos = np.einsum("ij,ij->i", guest.inward, -host_inward)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _adjacent_face_pairs(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of faces sharing an edge and that edge.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)

    Returns
    -------
    pairs : ndarray of int64, shape (p, 2)
        Face indices (an edge with ``j > 2`` faces gives ``j − 1`` pairs).
        Ordered by edge (``lo * n + hi``), and along an edge by the face's
        half-edge: all first edges (vertex 0 to 1) of the faces in face
        order, then all second edges, then all third edges.
    edges : ndarray of int64, shape (p, 2)
        The shared edge of each pair, smaller vertex first.
    """
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    n = int(F.max()) + 1 if m else 1
    FT = np.ascontiguousarray(F.T)  # (3, m)
    start = FT.reshape(-1)  # half-edge h = e * m + f runs from F[f, e] to F[f, (e + 1) % 3]
    end = FT[[1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    key = lo * n + hi
    order = _stable_key_order(key, n * n)
    k = key[order]
    same = np.flatnonzero(k[1:] == k[:-1])
    first, second = order[same], order[same + 1]
    pairs = np.stack([first % m, second % m], axis=1) if m else np.zeros((0, 2), np.int64)
    edges = np.stack([lo[first], hi[first]], axis=1)
    return pairs, edges


def _stable_key_order(key: np.ndarray, bound: int) -> np.ndarray:
    """``np.argsort(key, kind="stable")`` for non-negative int64 keys below ``bound``.

    Sorts ``key * len(key) + position`` instead, all distinct, so any sort
    gives the stable order (an unstable value sort is faster than a stable
    arg sort); falls back to the arg sort where that product would overflow.

    Parameters
    ----------
    key : ndarray of int64, shape (h,)
    bound : int
        Exclusive upper bound of the keys.

    Returns
    -------
    ndarray of int64, shape (h,)
    """
    h = len(key)
    if h == 0 or bound * h >= np.iinfo(np.int64).max:
        return np.argsort(key, kind="stable")
    return np.sort(key * h + np.arange(h, dtype=np.int64)) % h


def edge_dihedral_angles(
    V: np.ndarray, F: np.ndarray, faces: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Angle between the normals of every two faces sharing an edge.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    faces : ndarray of bool, shape (m,), optional
        Only edges whose two faces are both selected are measured.

    Returns
    -------
    edges : ndarray of int64, shape (p, 2)
        Interior edges measured (smaller vertex first).
    angles : ndarray, shape (p,)
        Degrees in ``[0, 180]``: 0 where the two faces are coplanar (flat),
        ``360/k`` across a side edge of a regular ``k``-sided prism.

    Notes
    -----
    This is the turning angle between the faces (the exterior dihedral
    angle), unsigned; :func:`igl.dihedral_angles` is a different quantity
    (interior angles of tetrahedra).
    """
    pairs, edges = _adjacent_face_pairs(F)
    if faces is not None:
        keep = np.asarray(faces, dtype=bool)[pairs].all(axis=1)
        pairs, edges = pairs[keep], edges[keep]
    N, _ = face_normals_areas(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))
    cos = _pair_cosines(N, np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1]))
    return edges, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def ring_band(F: np.ndarray, vertices: np.ndarray, rings: int) -> np.ndarray:
    """Faces within ``rings`` rings of a set of vertices.

    Ring 1 is the faces using one of ``vertices``; ring ``r + 1`` adds the
    faces using a vertex of ring ``r``.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
    vertices : ndarray of int64, shape (k,)
        E.g. the seam or a boundary curve.
    rings : int
        At least 1.

    Returns
    -------
    ndarray of bool, shape (m,)
    """
    F = np.asarray(F, dtype=np.int64)
    _check_rings(rings)
    vertices = np.asarray(vertices, dtype=np.int64).reshape(-1)
    size = max(int(F.max()) + 1 if F.size else 0, int(vertices.max()) + 1 if vertices.size else 0)
    FT = np.ascontiguousarray(F.T)  # (3, m): one contiguous column per corner
    mark = np.zeros(size, dtype=bool)
    mark[vertices] = True
    band = mark[FT[0]] | mark[FT[1]] | mark[FT[2]]
    for _ in range(int(rings) - 1):
        mark[FT[:, band]] = True
        band = mark[FT[0]] | mark[FT[1]] | mark[FT[2]]
    return band


def _check_rings(rings) -> None:
    """Raise :class:`OptionsError` unless ``rings`` is a positive integer (not a bool)."""
    if isinstance(rings, bool) or not isinstance(rings, (int, np.integer)) or rings < 1:
        raise OptionsError(
            f"rings={rings!r} must be a positive integer (1 = the faces at the vertices)"
        )


def host_dihedral_angles(
    V: np.ndarray, F: np.ndarray, curve: np.ndarray, rings: int = HOST_DIHEDRAL_RINGS
) -> np.ndarray:
    """Dihedral angles of the host's own edges near its boundary curve.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
        Host mesh.
    curve : ndarray of int64, shape (k,)
        Host curve vertices.
    rings : int
        Faces within this many rings of the curve (:func:`ring_band`) take part.

    Returns
    -------
    ndarray, shape (p,)
        Degrees, one per interior edge of that band (see
        :func:`edge_dihedral_angles`): the host's own creases, the scale
        against which the seam crease (:func:`crease_angles`) is judged.
    """
    F = np.asarray(F, dtype=np.int64)
    curve = np.asarray(curve, dtype=np.int64)
    _check_rings(rings)
    memo = _mesh_memo(V, F)
    key = ("host_dihedral_angles", curve.tobytes(), int(rings))
    if key not in memo:
        angles = edge_dihedral_angles(V, F[ring_band(F, curve, rings)])[1]
        angles.flags.writeable = False
        memo[key] = angles
    return memo[key].copy()


def self_intersections(V: np.ndarray, F: np.ndarray, faces: np.ndarray | None = None) -> np.ndarray:
    """Pairs of faces that intersect other than along a shared edge or vertex.

    Uses CGAL's exact predicates through libigl
    (``igl.copyleft.cgal.remesh_self_intersections`` with ``detect_only``):
    faces sharing a vertex or an edge count only if they also overlap
    elsewhere (e.g. coplanar overlapping or folded-through neighbours).

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    faces : ndarray of bool, shape (m,), optional
        Test only these faces against each other (e.g. :func:`ring_band`
        around the seam).

    Returns
    -------
    ndarray of int64, shape (p, 2)
        Intersecting face pairs (indices into ``F``), smaller first, sorted.

    Notes
    -----
    CGAL's cost grows with the faces it is given: on this machine (medians)
    3.0 ms for the 1,200-1,900 faces at the seam of a half-resolution paper
    sample, 5.7 ms at full resolution and 32 ms at twice the resolution
    (about 1.5-3 % of those joins). A floating-point pre-check that kept
    clean faces from CGAL saved 2.3, 4.1 and 25 ms of that but cost 16-36
    ms on its first call in every process (numba loading its compiled
    code), so it was removed.
    """
    import igl.copyleft.cgal as cgal  # compiled CGAL bindings: load on first use

    F = np.asarray(F, dtype=np.int64)
    sel = np.arange(len(F)) if faces is None else np.flatnonzero(np.asarray(faces, dtype=bool))
    if sel.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    V = np.asarray(V, dtype=np.float64)
    sub = F[sel]
    # the vertices used, ascending, and the faces renumbered onto them (as np.unique would)
    used = np.zeros(len(V), dtype=bool)
    used[sub.reshape(-1)] = True
    used = np.flatnonzero(used)
    lookup = np.zeros(len(V), dtype=np.int64)
    lookup[used] = np.arange(len(used))
    Vs = np.ascontiguousarray(V[used])
    Fs = np.ascontiguousarray(lookup[sub])
    pairs = cgal.remesh_self_intersections(Vs, Fs, detect_only=True)[2]
    pairs = sel[np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs, axis=0) if len(pairs) else pairs


def point_polyline_distance(P: np.ndarray, C: np.ndarray, closed: bool) -> np.ndarray:
    """Distance of each point to a polyline.

    Parameters
    ----------
    P : ndarray, shape (p, 3)
    C : ndarray, shape (k, 3)
        Polyline vertices in order.
    closed : bool
        The polyline returns from ``C[-1]`` to ``C[0]``.

    Returns
    -------
    ndarray, shape (p,)
        The smallest distance to a segment, each segment's distance taken at
        the clamped projection of the point onto it.

    Notes
    -----
    Long inputs measure each point only against the segments that can be
    nearest (:func:`_near_segments`); the distances are the same floats as
    those of measuring every segment.
    """
    P = np.asarray(P, dtype=np.float64)
    C = np.asarray(C, dtype=np.float64)
    A = C
    B = np.roll(C, -1, axis=0) if closed else C[1:]
    A = A[: len(B)]
    AB = B - A
    ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    if len(P) * len(A) <= _DENSE_PAIRS or len(A) == 0:
        out = np.empty(len(P))
        chunk = max(1, 2_000_000 // max(len(A), 1))
        for s in range(0, len(P), chunk):
            Q = P[s : s + chunk]
            t = np.clip(np.einsum("pkj,kj->pk", Q[:, None, :] - A[None], AB) / ab2, 0.0, 1.0)
            D = A[None] + t[..., None] * AB[None] - Q[:, None, :]
            out[s : s + chunk] = np.sqrt(np.einsum("pkj,pkj->pk", D, D).min(axis=1))
        return out
    point, seg = _near_segments(P, A, AB)
    return _segment_distances(P, A, AB, ab2, point, seg, len(P))


#: Point-segment pairs up to which :func:`point_polyline_distance` measures all pairs.
_DENSE_PAIRS = 4096


def _segment_distances(P, A, AB, ab2, point, seg, p) -> np.ndarray:
    """Smallest distance of each point to its listed segments.

    Parameters
    ----------
    P : ndarray, shape (p, 3)
    A, AB : ndarray, shape (k, 3)
        Segment starts and vectors.
    ab2 : ndarray, shape (k,)
        Squared segment lengths (at least ``1e-300``).
    point, seg : ndarray of int64, shape (c,)
        Pairs to measure, in any order, every point at least once.
    p : int

    Returns
    -------
    ndarray, shape (p,)
    """
    Q = P[point]
    As, ABs = A[seg], AB[seg]
    t = np.clip(np.einsum("cj,cj->c", Q - As, ABs) / ab2[seg], 0.0, 1.0)
    D = As + t[:, None] * ABs - Q
    d = np.sqrt(np.einsum("cj,cj->c", D, D))
    out = np.full(p, np.inf)
    np.minimum.at(out, point, d)
    return out


def _near_segments(P: np.ndarray, A: np.ndarray, AB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point-segment pairs that include, for each point, every segment that can be nearest.

    A segment with midpoint ``M`` and half length ``r`` is at least
    ``|P − M| − r`` from ``P``. Measuring the segment with the nearest
    midpoint gives an upper bound ``d`` on the distance; a segment can only
    beat it if ``|P − M| ≤ d + r``, so the segments with midpoints within
    ``d + max r`` (plus a margin far above rounding) are listed.

    Parameters
    ----------
    P : ndarray, shape (p, 3)
    A, AB : ndarray, shape (k, 3)
        Segment starts and vectors.

    Returns
    -------
    point, seg : ndarray of int64, shape (c,)
        The pairs, every point at least once.
    """
    k = len(A)
    M = A + 0.5 * AB
    ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    half = 0.5 * np.sqrt(ab2)
    tree = cKDTree(M)
    _, nearest = tree.query(P)
    upper = _segment_distances(P, A, AB, ab2, np.arange(len(P)), nearest, len(P))
    scale = max(float(np.abs(P).max()), float(np.abs(M).max()), float(half.max()))
    radius = upper + half.max() + 1e-9 * scale  # 1e-9: far above the rounding of any term
    # the midpoints within each radius: ask for `count` neighbours, twice as many for the
    # points whose last one is still inside their radius
    point = np.arange(len(P))
    found_point, found_seg = [], []
    count = min(k, 8)
    while point.size:
        dist, idx = tree.query(P[point], k=count, distance_upper_bound=float(radius[point].max()))
        dist, idx = dist.reshape(len(point), count), idx.reshape(len(point), count)
        inside = dist <= radius[point, None]
        more = inside[:, -1] & (count < k)
        done = ~more
        rows, cols = np.nonzero(inside[done])
        found_point.append(point[done][rows])
        found_seg.append(idx[done][rows, cols])
        point = point[more]
        count = min(k, 2 * count)
    return np.concatenate(found_point), np.concatenate(found_seg).astype(np.int64)


def seam_gap(seam_points: np.ndarray, host_points: np.ndarray, closed: bool) -> dict:
    """Distance of the guest seam to the host curve.

    Parameters
    ----------
    seam_points : ndarray, shape (s, 3)
        Deformed guest seam vertices.
    host_points : ndarray, shape (k, 3)
        Host curve polyline.
    closed : bool

    Returns
    -------
    dict
        ``max``, ``mean`` (absolute), ``relative_max``, ``relative_mean``
        (divided by the mean host seam edge).
    """
    d = point_polyline_distance(seam_points, host_points, closed)
    seg = np.roll(host_points, -1, axis=0) - host_points if closed else np.diff(host_points, axis=0)
    mean_edge = float(np.linalg.norm(seg, axis=1).mean())
    return {
        "max": float(d.max()),
        "mean": float(d.mean()),
        "relative_max": float(d.max() / mean_edge),
        "relative_mean": float(d.mean() / mean_edge),
    }


def folded_pairs(V0: np.ndarray, V1: np.ndarray, F: np.ndarray, angle: float = 150.0) -> np.ndarray:
    """Adjacent face pairs whose normals turned against each other.

    A pair counts when the angle between the two faces' normals exceeds
    ``angle`` degrees in the deformed mesh but not in the rest mesh.

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    angle : float

    Returns
    -------
    ndarray of int64, shape (p, 2)
        Face index pairs.
    """
    pairs, _ = _adjacent_face_pairs(F)
    if not len(pairs):
        return pairs
    limit = np.cos(np.radians(angle))
    n0, _ = face_normals_areas(V0, F)
    n1, _ = face_normals_areas(V1, F)
    first, second = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    c0 = _pair_cosines(n0, first, second)
    c1 = _pair_cosines(n1, first, second)
    return pairs[(c1 < limit) & (c0 >= limit)]


def _pair_cosines(N: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Dot products ``N[first[i]] · N[second[i]]`` of unit normals ``N`` (m, 3) -> (p,).

    Gathers the rows with ``np.take`` (faster than fancy indexing) into the
    same (p, 3) arrays, so ``einsum`` sums them as it does those.
    """
    return np.einsum("ij,ij->i", np.take(N, first, axis=0), np.take(N, second, axis=0))


def summary(values: np.ndarray) -> dict:
    """Mean, median, 95th percentile, min and max of finite values, as floats."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": None, "median": None, "p95": None, "min": None, "max": None}
    return {
        "mean": float(v.mean()),
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95)),
        "min": float(v.min()),
        "max": float(v.max()),
    }
