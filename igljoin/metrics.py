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
    the faces near the seam (:func:`ring_band`) are tested, and only those
    that a floating-point pre-check with proven signs cannot set apart from
    all the others reach CGAL, which keeps it cheap enough to run on every
    join.
"""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from . import correspond, frames
from .correspond import RigidReference
from .errors import OptionsError
from .frames import CurveFaces, face_areas, face_normals_areas, seam_frames
from .polyline import mean_segment
from .seam_geometry import SeamGeometry

__all__ = [
    "area_ratio",
    "edge_strain",
    "vertex_strain",
    "vertex_incidence",
    "VertexIncidence",
    "nonrigid_displacement",
    "crease_angles",
    "guest_curve_faces",
    "edge_dihedral_angles",
    "host_dihedral_angles",
    "ring_band",
    "self_intersections",
    "seam_gap",
    "folded_pairs",
    "fold_reference",
    "FoldReference",
    "edge_lengths",
    "summary",
    "point_polyline_distance",
    "PolylineDistance",
]

#: Default number of vertex rings around the seam searched for self-intersections.
SELF_INTERSECTION_RINGS = 3

#: Default number of rings around the host curve whose dihedral angles are measured.
HOST_DIHEDRAL_RINGS = 2


def area_ratio(
    V0: np.ndarray,
    V1: np.ndarray,
    F: np.ndarray,
    *,
    rest_areas: np.ndarray | None = None,
    areas: np.ndarray | None = None,
) -> np.ndarray:
    """Deformed over rest area of each face (the paper's deformation display).

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
        Rest and deformed positions.
    F : ndarray of int64, shape (m, 3)
    rest_areas, areas : ndarray, shape (m,), optional
        ``face_areas(V0, F)`` and ``face_areas(V1, F)``, if already made
        (a solver keeps its rest guest's).

    Returns
    -------
    ndarray, shape (m,)
        1 where a face kept its area, > 1 stretched, < 1 shrunk.
    """
    a0 = face_areas(V0, F) if rest_areas is None else rest_areas
    a1 = face_areas(V1, F) if areas is None else areas
    return a1 / np.where(a0 > 0, a0, np.nan)


def edge_strain(
    V0: np.ndarray, V1: np.ndarray, E: np.ndarray, *, rest_lengths: np.ndarray | None = None
) -> np.ndarray:
    """Relative length change ``(ℓ′ − ℓ)/ℓ`` of each edge ``E`` (shape (e, 2)) -> (e,).

    ``rest_lengths`` (e,): the edges' lengths in ``V0``, if already made
    (:func:`edge_lengths`).
    """
    E = np.asarray(E)
    l0 = edge_lengths(V0, E) if rest_lengths is None else rest_lengths
    l1 = edge_lengths(V1, E)
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


def edge_lengths(V: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Length of each edge ``V[E[:, 0]] − V[E[:, 1]]``, shape (e,), for ``E`` of shape (e, 2)."""
    VT = np.ascontiguousarray(np.asarray(V).T)  # (3, n)
    ET = np.ascontiguousarray(np.asarray(E).T)  # (2, e)
    return _row_norms(np.take(VT, ET[0], axis=1) - np.take(VT, ET[1], axis=1))


def vertex_strain(
    E: np.ndarray, strain: np.ndarray, n: int, *, incidence: VertexIncidence | None = None
) -> np.ndarray:
    """Per-vertex strain: the mean strain of the edges incident to each vertex.

    Parameters
    ----------
    E : ndarray of int64, shape (e, 2)
        Undirected edges, each listed once.
    strain : ndarray, shape (e,)
        Per-edge strain (:func:`edge_strain`); non-finite values are ignored.
    n : int
        Number of vertices.
    incidence : VertexIncidence, optional
        ``vertex_incidence(E, n)``, if already made (a solver keeps its rest
        guest's); used where every strain is finite.

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
    if incidence is None or not ok.all():
        incidence = vertex_incidence(E[ok], n)
        s = s[ok]
    ends, count = incidence
    total = np.bincount(ends, weights=np.repeat(s, 2), minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


class VertexIncidence(NamedTuple):
    """The edges' side of :func:`vertex_strain`.

    Attributes
    ----------
    ends : ndarray of int64, shape (2e,)
        The edges' end vertices, edge after edge.
    count : ndarray of int64, shape (n,)
        Edges incident to each vertex.
    """

    ends: np.ndarray
    count: np.ndarray


def vertex_incidence(E: np.ndarray, n: int) -> VertexIncidence:
    """The end vertices of the edges ``E`` (e, 2) and each of ``n`` vertices' edge count."""
    ends = np.asarray(E, dtype=np.int64).reshape(-1)
    return VertexIncidence(ends, np.bincount(ends, minlength=n))


def nonrigid_displacement(
    V0: np.ndarray, V1: np.ndarray, *, rest: RigidReference | None = None
) -> np.ndarray:
    """Distance of each deformed vertex from the rigidly aligned rest vertex.

    The rest positions are first moved onto the deformed ones by the proper
    rotation and translation that minimise the summed squared distances
    (Kabsch); what remains is the deformation, not the placement.

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
        Rest and deformed positions.
    rest : RigidReference, optional
        :func:`igljoin.correspond.rigid_reference` of ``V0`` (float64), if
        already made (a solver keeps its rest guest's).

    Returns
    -------
    ndarray, shape (n,)
        In the mesh's length unit (mm for the phantoms); 0 for a rigid motion.
    """
    V0 = np.asarray(V0, dtype=np.float64)
    V1 = np.asarray(V1, dtype=np.float64)
    R, t = correspond.rigid_fit_to(correspond.rigid_reference(V0) if rest is None else rest, V1)
    return _row_norms(np.ascontiguousarray((V1 - (V0 @ R.T + t)).T))


def crease_angles(
    seam: SeamGeometry,
    host_inward: np.ndarray | None = None,
    *,
    guest_faces: CurveFaces | None = None,
) -> np.ndarray:
    """One-ring crease angle in degrees at each host curve vertex.

    Parameters
    ----------
    seam : SeamGeometry
        The host, its curve and the guest lying on it, as in
        :func:`igljoin.crease.seam_crease`.
    host_inward : ndarray, shape (k, 3), optional
        The host's one-ring inward directions along the curve
        (:func:`igljoin.frames.seam_frames`), if already made (a solver keeps
        them for its rigid host).
    guest_faces : CurveFaces, optional
        ``guest_curve_faces(seam)`` of a guest with the same faces and curve, if
        already made (a solver keeps its rest guest's): the guest's one-ring
        frames (:func:`igljoin.frames.curve_frames`) then measure only what
        moves.

    Returns
    -------
    ndarray, shape (k,)
    """
    if host_inward is None:
        host_inward = seam_frames(seam.Vh, seam.Fh, seam.host_curve, seam.closed).inward
    kept = guest_curve_faces(seam) if guest_faces is None else guest_faces
    guest = frames.curve_frames(seam.Vg, kept).inward
    cos = np.einsum("ij,ij->i", guest, -host_inward)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def guest_curve_faces(seam: SeamGeometry) -> CurveFaces:
    """:func:`igljoin.frames.curve_faces` of the guest of ``seam`` along its curve.

    The guest's faces at the curve, their incidence and the host curve's
    points and tangents: what its one-ring frames take from all but its
    positions.
    """
    return frames.curve_faces(
        seam.Fg, seam.guest_at_host, len(seam.Vg), seam.host_points, seam.closed
    )


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
    return edge_dihedral_angles(V, F[ring_band(F, curve, rings)])[1]


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
    Faces that a floating-point pre-check proves apart from every other
    tested face (:func:`_apart_faces`) are not handed to CGAL; whatever CGAL would
    find involves only faces that remain, so the pairs are the same. On a
    clean join few or no faces remain and CGAL is not called; its cost
    grows with the faces it is given (about 4 ms for 1,200–1,900 faces).

    The pre-check is kept for its speed, measured on the bands the joins
    pass (one call per join; medians on this machine): 0.80 / 1.64 / 7.0 ms
    against 3.0 / 5.7 / 32 ms for CGAL alone at half, full and twice the
    paper resolution, i.e. 2.3 ms of a 31 ms join (7.3 %), 4.1 ms of a 176 ms
    paper join (2.3 %), 25 ms of a 2.55 s join (1.0 %); in joins run two at a
    time on two busy cores, paper joins were about 8 % slower without it
    (median of 84 paired joins). Its compiled code costs 16-36 ms on its
    first call in a process (numba loading it from the cache), which about
    ten paper joins in that process win back.
    """
    import igl.copyleft.cgal as cgal  # compiled CGAL bindings: load on first use

    F = np.asarray(F, dtype=np.int64)
    sel = np.arange(len(F)) if faces is None else np.flatnonzero(np.asarray(faces, dtype=bool))
    if sel.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    V = np.asarray(V, dtype=np.float64)
    sub = np.ascontiguousarray(F[sel])
    corners = np.ascontiguousarray(np.take(V, sub, axis=0))  # (b, 3 corners, 3 coordinates)
    sel = sel[~_apart(corners, sub)]
    if sel.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
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


# -- floating-point pre-check for self_intersections ------------------------------------------
#
# A pair of faces is "apart" when CGAL's test in libigl's SelfIntersectMesh cannot count it:
# their bounding boxes are disjoint, or a sign test below proves it. Every sign comes from a
# determinant computed in float64 next to a bound on its rounding error; a sign counts only
# where the determinant exceeds the bound, so a proof never rests on a rounded sign.
#
# The bound: the determinants are d . (p x q) with d, p, q differences of input coordinates
# (each rounded once) or vectors taken as given, evaluated as a dot product with a rounded
# cross product. Their error is below 10 eps * sum_k |d_k| (|p_i q_j| + |p_j q_i|)
# (eps = 2^-53, first order in eps; Shewchuk's orient3d bound is 7 eps times the same sum),
# and that of a dot product d . n with a given n below 4 eps * sum_k |d_k n_k|; _SIGN_BOUND
# uses 1e-12 (about 4,500 eps) times these sums. Sums below _SIGN_FLOOR are not used, so
# underflow (absolute errors near 1e-308) stays far below the bound. 2D orientations use
# Shewchuk's orient2d sum, whose bound is 3 eps times it.
_SIGN_BOUND = 1e-12
_SIGN_FLOOR = 1e-250

import numba as _nb  # noqa: E402 (a hard dependency; here beside the kernels it compiles)


def _sign(det: float, scale: float) -> int:
    """Sign of a determinant proven by its error bound: +1, −1, or 0 (not proven).

    Parameters
    ----------
    det : float
        The computed determinant.
    scale : float
        The sum of absolute products it bounds its rounding by (see above).
    """
    if not scale >= _SIGN_FLOOR:  # also NaN
        return 0
    if det > _SIGN_BOUND * scale:
        return 1
    if det < -_SIGN_BOUND * scale:
        return -1
    return 0


def _side(corners, g: int, c: int, f: int, k: int, axes, terms) -> int:
    """Proven side of corner ``c`` of face ``g`` of plane ``k`` of face ``f``.

    Parameters
    ----------
    corners : ndarray, shape (b, 3, 3)
        Corner coordinates of each face.
    g, c, f, k : int
        Plane ``k < 3`` runs through edge ``k`` of ``f`` along its normal;
        plane 3 is the plane of ``f`` (see :func:`_planes`).
    axes, terms : ndarray, shape (b, 4, 3)
        The planes' normals and their error terms.

    Returns
    -------
    int
        Sign of ``(corners[g, c] − origin) · axes[f, k]`` (origin: corner
        ``k`` of ``f``, corner 0 for its own plane), 0 where not proven.
    """
    o = k if k < 3 else 0
    d0 = corners[g, c, 0] - corners[f, o, 0]
    d1 = corners[g, c, 1] - corners[f, o, 1]
    d2 = corners[g, c, 2] - corners[f, o, 2]
    det = (d0 * axes[f, k, 0] + d1 * axes[f, k, 1]) + d2 * axes[f, k, 2]
    scale = (abs(d0) * terms[f, k, 0] + abs(d1) * terms[f, k, 1]) + abs(d2) * terms[f, k, 2]
    return _sign(det, scale)


def _planes(corners):
    """Planes through each face and through each of its edges.

    Parameters
    ----------
    corners : ndarray, shape (b, 3, 3)
        Corner coordinates of each face.

    Returns
    -------
    axes, terms : ndarray, shape (b, 4, 3)
        ``axes[f, 3] = (c1 − c0) × (c2 − c0)``, the normal of face ``f``
        (its plane runs through ``c0``); ``axes[f, e] = axes[f, 3] ×
        (c[e+1] − c[e])`` for edge ``e``, the normal of the plane through
        the edge along the face normal. ``terms`` holds, per component of
        each cross product ``p × q``, ``|p_i q_j| + |p_j q_i|``.
    sides : ndarray of int64, shape (b, 3)
        Proven side of the plane through edge ``e`` of the corner opposite
        the edge (0: not proven).
    """
    b = corners.shape[0]
    axes = np.empty((b, 4, 3))
    terms = np.empty((b, 4, 3))
    sides = np.zeros((b, 3), dtype=np.int64)
    p = np.empty(3)
    q = np.empty(3)
    for f in range(b):
        for k in range(3):
            p[k] = corners[f, 1, k] - corners[f, 0, k]
            q[k] = corners[f, 2, k] - corners[f, 0, k]
        for i in range(3):
            x, y = p[(i + 1) % 3] * q[(i + 2) % 3], p[(i + 2) % 3] * q[(i + 1) % 3]
            axes[f, 3, i] = x - y
            terms[f, 3, i] = abs(x) + abs(y)
        for e in range(3):
            for k in range(3):
                q[k] = corners[f, (e + 1) % 3, k] - corners[f, e, k]
            for i in range(3):
                x = axes[f, 3, (i + 1) % 3] * q[(i + 2) % 3]
                y = axes[f, 3, (i + 2) % 3] * q[(i + 1) % 3]
                axes[f, e, i] = x - y
                terms[f, e, i] = abs(x) + abs(y)
        for e in range(3):
            sides[f, e] = _side(corners, f, (e + 2) % 3, f, e, axes, terms)
    return axes, terms, sides


def _orient2d(corners, f: int, p: int, q: int, g: int, r: int, u: int, v: int) -> int:
    """Proven sign of the orientation of corners ``p, q`` of ``f`` and ``r`` of ``g``.

    Projected on coordinates ``u, v``; 0 where not proven.
    """
    t1 = (corners[f, p, u] - corners[g, r, u]) * (corners[f, q, v] - corners[g, r, v])
    t2 = (corners[f, p, v] - corners[g, r, v]) * (corners[f, q, u] - corners[g, r, u])
    return _sign(t1 - t2, abs(t1) + abs(t2))


def _pair_apart(i: int, j: int, corners, F, axes, terms, sides) -> bool:
    """Whether CGAL's test provably does not count faces ``i`` and ``j``.

    By the vertices they share (by index):

    * three: libigl skips duplicate faces.
    * two: libigl counts the pair only if the other corner of ``i`` lies on
      the plane of ``j`` and the two other corners lie on the same side of
      the shared edge; apart if the corner is proven off the plane, or the
      two corners proven on opposite sides of the edge in a coordinate
      projection (where the four points are coplanar, a projection that
      keeps them apart keeps their sides).
    * one or none: apart when a plane has one face on one closed side and
      the other face's corners, but for shared ones on the plane, strictly
      on the other side: then the faces meet at most in the shared vertex.
      Tried: each face's plane, the planes through each face's edges along
      its normal, then, with a shared vertex, :func:`_wedges_apart`.
    """
    shared = 0
    for a in range(3):
        for b in range(3):
            if F[i, a] == F[j, b]:
                shared += 1
    if shared >= 3:
        return True
    if shared == 2:
        oa, ob = 0, 0
        for a in range(3):
            if F[i, a] != F[j, 0] and F[i, a] != F[j, 1] and F[i, a] != F[j, 2]:
                oa = a
            if F[j, a] != F[i, 0] and F[j, a] != F[i, 1] and F[j, a] != F[i, 2]:
                ob = a
        if _side(corners, i, oa, j, 3, axes, terms) != 0:
            return True
        s0, s1 = (oa + 1) % 3, (oa + 2) % 3
        for k in range(3):
            u, v = (k + 1) % 3, (k + 2) % 3
            sa = _orient2d(corners, i, s0, s1, i, oa, u, v)
            if sa != 0 and sa == -_orient2d(corners, i, s0, s1, j, ob, u, v):
                return True
        return False
    for turn in range(2):
        f, g = (i, j) if turn == 0 else (j, i)
        for k in range(3, -1, -1):  # the face's own plane first, then its edges' planes
            want = 0 if k == 3 else -sides[f, k]
            if k < 3 and want == 0:
                continue
            ok = True
            for c in range(3):
                x = F[g, c]
                if k == 3:
                    if x == F[f, 0] or x == F[f, 1] or x == F[f, 2]:
                        continue  # a shared vertex lies on the plane
                elif x == F[f, k] or x == F[f, (k + 1) % 3]:
                    continue  # an end of the edge lies on its plane
                s = _side(corners, g, c, f, k, axes, terms)
                if s == 0 or (want != 0 and s != want):
                    ok = False
                    break
                want = s
            if ok:
                return True
    return shared == 1 and _wedges_apart(i, j, corners, F, axes)


def _plane_side(d0: float, d1: float, d2: float, n0: float, n1: float, n2: float) -> int:
    """Proven sign of ``d · n`` for a difference ``d`` (rounded once) and a given vector ``n``."""
    det = (d0 * n0 + d1 * n1) + d2 * n2
    return _sign(det, (abs(d0 * n0) + abs(d1 * n1)) + abs(d2 * n2))


def _wedges_apart(i: int, j: int, corners, F, axes) -> bool:
    """Whether faces ``i`` and ``j``, sharing one vertex, meet only there.

    Tries planes through the shared vertex that contain ``w``, the sum of
    the two unit normals: the plane through an edge at the shared vertex
    (its far end then lies on the plane), and the planes along the sum of
    one unit edge direction of each face, which run between the faces where
    edges of one line up with edges of the other (as on a structured grid,
    where every other plane through an edge touches the other face). Apart
    when one face's other corners are proven on one side and the other
    face's on the other side.
    """
    si, sj = 0, 0
    for a in range(3):
        for b in range(3):
            if F[i, a] == F[j, b]:
                si, sj = a, b
    li = np.sqrt(axes[i, 3, 0] ** 2 + axes[i, 3, 1] ** 2 + axes[i, 3, 2] ** 2)
    lj = np.sqrt(axes[j, 3, 0] ** 2 + axes[j, 3, 1] ** 2 + axes[j, 3, 2] ** 2)
    if not (li > 0 and lj > 0):
        return False
    w = np.empty(3)
    for k in range(3):
        w[k] = axes[i, 3, k] / li + axes[j, 3, k] / lj
    # edges from the shared vertex: rows 0, 1 of face i, rows 2, 3 of face j
    edge = np.empty((4, 3))
    unit = np.empty((4, 3))
    for r in range(4):
        f, c0, c = (i, si, (si + 1 + r) % 3) if r < 2 else (j, sj, (sj + r - 1) % 3)
        for k in range(3):
            edge[r, k] = corners[f, c, k] - corners[f, c0, k]
        length = np.sqrt(edge[r, 0] ** 2 + edge[r, 1] ** 2 + edge[r, 2] ** 2)
        if not length > 0:
            return False
        for k in range(3):
            unit[r, k] = edge[r, k] / length
    axis = np.empty(3)
    terms = np.empty(3)
    # the plane through edge r along w; its face's other edge on one side, the other face's
    # two edges on the other
    for r in range(4):
        for k in range(3):
            a = w[(k + 1) % 3] * edge[r, (k + 2) % 3]
            b = w[(k + 2) % 3] * edge[r, (k + 1) % 3]
            axis[k] = a - b
            terms[k] = abs(a) + abs(b)
        mate = r ^ 1
        own = _sign(
            (edge[mate, 0] * axis[0] + edge[mate, 1] * axis[1]) + edge[mate, 2] * axis[2],
            (abs(edge[mate, 0]) * terms[0] + abs(edge[mate, 1]) * terms[1])
            + abs(edge[mate, 2]) * terms[2],
        )
        if own == 0:
            continue
        ok = True
        other = 2 if r < 2 else 0
        for q in range(other, other + 2):
            x = edge[q]
            s = _sign(
                (x[0] * axis[0] + x[1] * axis[1]) + x[2] * axis[2],
                (abs(x[0]) * terms[0] + abs(x[1]) * terms[1]) + abs(x[2]) * terms[2],
            )
            if s != -own:
                ok = False
                break
        if ok:
            return True
    # the planes along w and a direction between the faces
    n = np.empty(3)
    for p in range(2):
        for q in range(2, 4):
            for k in range(3):
                d1 = unit[p, (k + 1) % 3] + unit[q, (k + 1) % 3]
                d2 = unit[p, (k + 2) % 3] + unit[q, (k + 2) % 3]
                n[k] = d1 * w[(k + 2) % 3] - d2 * w[(k + 1) % 3]
            first = _plane_side(edge[0, 0], edge[0, 1], edge[0, 2], n[0], n[1], n[2])
            second = _plane_side(edge[1, 0], edge[1, 1], edge[1, 2], n[0], n[1], n[2])
            if first == 0 or second != first:
                continue
            if (
                _plane_side(edge[2, 0], edge[2, 1], edge[2, 2], n[0], n[1], n[2]) == -first
                and _plane_side(edge[3, 0], edge[3, 1], edge[3, 2], n[0], n[1], n[2]) == -first
            ):
                return True
    return False


def _apart_faces(corners, F):
    """Faces proven apart from every other face (see :func:`_pair_apart`).

    Parameters
    ----------
    corners : ndarray, shape (b, 3, 3)
        Corner coordinates of each face.
    F : ndarray of int64, shape (b, 3)
        Their vertex indices.

    Returns
    -------
    ndarray of bool, shape (b,)

    Notes
    -----
    Pairs come from a sweep along the coordinate axis where the fewest
    boxes start before another box ends: sorted by their lower ends, each
    box meets the boxes that start before it ends; pairs whose closed boxes
    are disjoint are apart.
    """
    b = corners.shape[0]
    lo = np.empty((3, b))
    hi = np.empty((3, b))
    for f in range(b):
        for k in range(3):
            lo[k, f] = min(corners[f, 0, k], corners[f, 1, k], corners[f, 2, k])
            hi[k, f] = max(corners[f, 0, k], corners[f, 1, k], corners[f, 2, k])
    axis, fewest = 0, -1
    order = np.arange(b)
    for k in range(3):
        by_start = np.argsort(lo[k], kind="mergesort")
        visits = np.searchsorted(lo[k][by_start], hi[k], side="right").sum()
        if fewest < 0 or visits < fewest:
            axis, fewest, order = k, visits, by_start
    slo = np.empty((3, b))  # boxes in sweep order
    shi = np.empty((3, b))
    for ii in range(b):
        for k in range(3):
            slo[k, ii] = lo[k, order[ii]]
            shi[k, ii] = hi[k, order[ii]]
    axes, terms, sides = _planes(corners)
    near = np.zeros(b, dtype=np.bool_)
    for ii in range(b):
        i = order[ii]
        for jj in range(ii + 1, b):
            if slo[axis, jj] > shi[axis, ii]:
                break
            if (
                slo[0, jj] > shi[0, ii]
                or slo[0, ii] > shi[0, jj]
                or slo[1, jj] > shi[1, ii]
                or slo[1, ii] > shi[1, jj]
                or slo[2, jj] > shi[2, ii]
                or slo[2, ii] > shi[2, jj]
            ):
                continue
            j = order[jj]
            if near[i] and near[j]:
                continue
            if not _pair_apart(i, j, corners, F, axes, terms, sides):
                near[i] = True
                near[j] = True
    return ~near


#: The pre-check's helpers compiled in place by numba (cached on disk), then
#: ``_apart(corners, F)``: :func:`_apart_faces` compiled.
_sign = _nb.njit(cache=True, inline="always")(_sign)
_side = _nb.njit(cache=True, inline="always")(_side)
_planes = _nb.njit(cache=True)(_planes)
_orient2d = _nb.njit(cache=True, inline="always")(_orient2d)
_plane_side = _nb.njit(cache=True, inline="always")(_plane_side)
_wedges_apart = _nb.njit(cache=True)(_wedges_apart)
_pair_apart = _nb.njit(cache=True, inline="always")(_pair_apart)
_apart = _nb.njit(cache=True)(_apart_faces)


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
    those of measuring every segment. :class:`PolylineDistance` keeps the
    polyline's side for points measured again.
    """
    return PolylineDistance(C, closed)(P)


#: Point-segment pairs up to which :func:`point_polyline_distance` measures all pairs.
_DENSE_PAIRS = 4096


class PolylineDistance:
    """:func:`point_polyline_distance` to one polyline, its segments' values made once.

    A solver keeps one per host curve (the host does not move), so a seam
    gap measures only the seam: the segments, their midpoints and their
    search tree are made once.

    Parameters
    ----------
    C : ndarray, shape (k, 3)
        Polyline vertices in order.
    closed : bool
        The polyline returns from ``C[-1]`` to ``C[0]``.

    Examples
    --------
    >>> import numpy as np
    >>> to_axis = PolylineDistance(np.array([[0.0, 0, 0], [1.0, 0, 0]]), closed=False)
    >>> to_axis(np.array([[0.5, 2.0, 0.0], [3.0, 0.0, 0.0]]))
    array([2., 2.])
    """

    def __init__(self, C: np.ndarray, closed: bool):
        C = np.asarray(C, dtype=np.float64)
        self.C, self.closed = C, bool(closed)
        B = np.roll(C, -1, axis=0) if closed else C[1:]
        self.A = C[: len(B)]
        self.AB = B - self.A
        self.ab2 = np.maximum(np.einsum("ij,ij->i", self.AB, self.AB), 1e-300)

    def __call__(self, P: np.ndarray) -> np.ndarray:
        """Distance of each point ``P`` (p, 3) to the polyline, shape (p,)."""
        P = np.asarray(P, dtype=np.float64)
        A, AB, ab2 = self.A, self.AB, self.ab2
        if len(P) * len(A) <= _DENSE_PAIRS or len(A) == 0:
            out = np.empty(len(P))
            chunk = max(1, 2_000_000 // max(len(A), 1))
            for s in range(0, len(P), chunk):
                Q = P[s : s + chunk]
                t = np.clip(np.einsum("pkj,kj->pk", Q[:, None, :] - A[None], AB) / ab2, 0.0, 1.0)
                D = A[None] + t[..., None] * AB[None] - Q[:, None, :]
                out[s : s + chunk] = np.sqrt(np.einsum("pkj,pkj->pk", D, D).min(axis=1))
            return out
        point, seg = _near_segments(P, A, AB, ab2, self._midpoints)
        return _segment_distances(P, A, AB, ab2, point, seg, len(P))

    @cached_property
    def mean_segment(self) -> float:
        """Mean segment length (:func:`igljoin.polyline.mean_segment`)."""
        return mean_segment(self.C, self.closed)

    @cached_property
    def _midpoints(self) -> _Midpoints:
        return _midpoints(self.A, self.AB, self.ab2)


class _Midpoints(NamedTuple):
    """The segments' side of :func:`_near_segments`: the largest half length, the
    coordinates' extent, the midpoints' search tree."""

    half_max: np.floating
    extent: float
    tree: cKDTree


def _midpoints(A: np.ndarray, AB: np.ndarray, ab2: np.ndarray) -> _Midpoints:
    """:class:`_Midpoints` of the segments from ``A`` along ``AB`` (each shape (k, 3)).

    ``ab2`` (k,) are their squared lengths, :attr:`PolylineDistance.ab2`.
    """
    M = A + 0.5 * AB
    half = 0.5 * np.sqrt(ab2)
    extent = max(float(np.abs(M).max()), float(half.max()))
    return _Midpoints(half.max(), extent, cKDTree(M))


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


def _near_segments(
    P: np.ndarray, A: np.ndarray, AB: np.ndarray, ab2: np.ndarray, kept: _Midpoints
) -> tuple[np.ndarray, np.ndarray]:
    """Point-segment pairs that include, for each point, every segment that can be nearest.

    A segment with midpoint ``M`` and half length ``r`` is at least
    ``|P − M| − r`` from ``P``. Measuring the segment with the nearest
    midpoint gives an upper bound ``d`` on the distance; a segment can only
    beat it if ``|P − M| ≤ d + r``, so the segments with midpoints within
    ``d + max r`` (plus a margin far above rounding) are listed. Whichever
    midpoint is taken as the nearest where two are as near, every segment
    whose distance can be the smallest is listed, so the smallest distance
    is the same.

    Parameters
    ----------
    P : ndarray, shape (p, 3)
    A, AB : ndarray, shape (k, 3)
        Segment starts and vectors.
    ab2 : ndarray, shape (k,)
        Squared segment lengths (at least ``1e-300``).
    kept : _Midpoints
        ``_midpoints(A, AB, ab2)`` (a :class:`PolylineDistance` keeps it).

    Returns
    -------
    point, seg : ndarray of int64, shape (c,)
        The pairs, every point at least once.
    """
    k, p = len(A), len(P)
    half_max, extent, tree = kept
    # the `count` nearest midpoints of every point: the nearest gives the bound
    count = min(k, 8)
    dist, idx = tree.query(P, k=count)
    dist, idx = dist.reshape(p, count), idx.reshape(p, count)
    upper = _segment_distances(P, A, AB, ab2, np.arange(p), idx[:, 0], p)
    scale = max(float(np.abs(P).max()), extent)
    radius = upper + half_max + 1e-9 * scale  # 1e-9: far above the rounding of any term
    # the midpoints within each radius: twice as many neighbours for the points whose
    # last one is still inside their radius
    point = np.arange(p)
    found_point, found_seg = [], []
    while True:
        inside = dist <= radius[point, None]
        more = inside[:, -1] & (count < k)
        done = ~more
        rows, cols = np.nonzero(inside[done])
        found_point.append(point[done][rows])
        found_seg.append(idx[done][rows, cols])
        point = point[more]
        if not point.size:
            return np.concatenate(found_point), np.concatenate(found_seg).astype(np.int64)
        count = min(k, 2 * count)
        dist, idx = tree.query(P[point], k=count, distance_upper_bound=float(radius[point].max()))
        dist, idx = dist.reshape(len(point), count), idx.reshape(len(point), count)


def seam_gap(seam_points: np.ndarray, host: PolylineDistance) -> dict:
    """Distance of the guest seam to the host curve.

    Parameters
    ----------
    seam_points : ndarray, shape (s, 3)
        Deformed guest seam vertices.
    host : PolylineDistance
        The distance to the host curve's polyline (k vertices),
        ``PolylineDistance(host_points, closed)`` (a solver keeps its rigid
        host's).

    Returns
    -------
    dict
        ``max``, ``mean`` (absolute), ``relative_max``, ``relative_mean``
        (divided by the mean host seam edge).
    """
    d = host(seam_points)
    mean_edge = host.mean_segment
    return {
        "max": float(d.max()),
        "mean": float(d.mean()),
        "relative_max": float(d.max() / mean_edge),
        "relative_mean": float(d.mean() / mean_edge),
    }


def folded_pairs(
    V0: np.ndarray,
    V1: np.ndarray,
    F: np.ndarray,
    angle: float = 150.0,
    *,
    rest: FoldReference | None = None,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """Adjacent face pairs whose normals turned against each other.

    A pair counts when the angle between the two faces' normals exceeds
    ``angle`` degrees in the deformed mesh but not in the rest mesh.

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    angle : float
    rest : FoldReference, optional
        ``fold_reference(V0, F)``, if already made (a solver keeps its rest
        guest's).
    normals : ndarray, shape (m, 3), optional
        The unit face normals of ``V1``
        (:func:`igljoin.frames.face_normals_areas`), if already made.

    Returns
    -------
    ndarray of int64, shape (p, 2)
        Face index pairs.
    """
    pairs, first, second, c0 = fold_reference(V0, F) if rest is None else rest
    if not len(pairs):
        return pairs
    limit = np.cos(np.radians(angle))
    n1 = face_normals_areas(V1, F)[0] if normals is None else normals
    c1 = _pair_cosines(n1, first, second)
    return pairs[(c1 < limit) & (c0 >= limit)]


class FoldReference(NamedTuple):
    """The rest mesh's side of :func:`folded_pairs`.

    Attributes
    ----------
    pairs : ndarray of int64, shape (p, 2)
        Adjacent face pairs (:func:`_adjacent_face_pairs`).
    first, second : ndarray of int64, shape (p,)
        Their columns, contiguous.
    cosines : ndarray, shape (p,)
        Cosine of the angle between each pair's rest normals.
    """

    pairs: np.ndarray
    first: np.ndarray
    second: np.ndarray
    cosines: np.ndarray


def fold_reference(V0: np.ndarray, F: np.ndarray) -> FoldReference:
    """The adjacent face pairs of ``F`` and their normals' cosines at rest ``V0`` (n, 3)."""
    pairs, _ = _adjacent_face_pairs(F)
    first, second = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    if not len(pairs):
        return FoldReference(pairs, first, second, np.zeros(0))
    n0, _ = face_normals_areas(V0, F)
    return FoldReference(pairs, first, second, _pair_cosines(n0, first, second))


def _pair_cosines(N: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Dot products ``N[first[i]] · N[second[i]]`` of unit normals ``N`` (m, 3) -> (p,).

    Gathers the rows with ``np.take`` (faster than fancy indexing) into the
    same (p, 3) arrays, so ``einsum`` sums them as it does those.
    """
    return np.einsum("ij,ij->i", np.take(N, first, axis=0), np.take(N, second, axis=0))


def summary(values: np.ndarray) -> dict:
    """Mean, median, 95th percentile, min and max of finite values, as floats."""
    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    if not finite.all():
        v = v[finite]
    if not v.size:
        return {"mean": None, "median": None, "p95": None, "min": None, "max": None}
    s = np.sort(v)
    n = len(s)
    half = n // 2
    median = s[half] if n % 2 else (s[half - 1] + s[half]) / 2.0
    return {
        # v.mean(): the sum in v's order over the count, without the call's overhead
        "mean": float(np.add.reduce(v) / n),
        "median": float(median),
        "p95": _percentile_sorted(s, 0.95),
        "min": float(s[0]),
        "max": float(s[-1]),
    }


def _percentile_sorted(s: np.ndarray, q: float) -> float:
    """``np.percentile(s, 100 q)`` (its default linear method) of sorted values ``s``, shape (n,).

    The same arithmetic as numpy's, step by step, so the values agree to the
    last bit; one sort serves the median and this, where the two numpy calls
    each partition the values again (a summary is taken some twenty times per
    join).
    """
    n = len(s)
    virtual = (n - 1) * q
    if virtual >= n - 1:
        return float(s[-1])
    if virtual < 0:
        return float(s[0])
    previous = np.floor(virtual)
    t = virtual - previous
    a, b = s[int(previous)], s[int(previous) + 1]
    diff = b - a
    return float(b - diff * (1.0 - t) if t >= 0.5 else a + diff * t)
