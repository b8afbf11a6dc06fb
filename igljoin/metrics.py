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

import numpy as np

from .correspond import rigid_fit
from .errors import OptionsError
from .frames import face_normals_areas, seam_frames

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
    _, a0 = face_normals_areas(V0, F)
    _, a1 = face_normals_areas(V1, F)
    return a1 / np.where(a0 > 0, a0, np.nan)


def edge_strain(V0: np.ndarray, V1: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Relative length change ``(ℓ′ − ℓ)/ℓ`` of each edge ``E`` (shape (e, 2)) -> (e,)."""
    l0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
    l1 = np.linalg.norm(V1[E[:, 0]] - V1[E[:, 1]], axis=1)
    return (l1 - l0) / np.where(l0 > 0, l0, np.nan)


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
    return np.linalg.norm(V1 - (V0 @ R.T + t), axis=1)


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
    host = seam_frames(Vh, Fh, host_curve, closed)
    guest = seam_frames(Vg, Fg, guest_at_host, closed, curve_points=Vh[host_curve])
    cos = np.einsum("ij,ij->i", guest.inward, -host.inward)
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
    edges : ndarray of int64, shape (p, 2)
        The shared edge of each pair, smaller vertex first.
    """
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    n = int(F.max()) + 1 if m else 1
    he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    face = np.tile(np.arange(m), 3)
    lo, hi = np.minimum(he[:, 0], he[:, 1]), np.maximum(he[:, 0], he[:, 1])
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    k = key[order]
    same = np.flatnonzero(k[1:] == k[:-1])
    pairs = np.stack([face[order[same]], face[order[same + 1]]], axis=1)
    edges = np.stack([lo[order[same]], hi[order[same]]], axis=1)
    return pairs, edges


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
    cos = np.einsum("ij,ij->i", N[pairs[:, 0]], N[pairs[:, 1]])
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
    if isinstance(rings, bool) or not isinstance(rings, (int, np.integer)) or rings < 1:
        raise OptionsError(
            f"rings={rings!r} must be a positive integer (1 = the faces at the vertices)"
        )
    vertices = np.asarray(vertices, dtype=np.int64).reshape(-1)
    size = max(int(F.max()) + 1 if F.size else 0, int(vertices.max()) + 1 if vertices.size else 0)
    mark = np.zeros(size, dtype=bool)
    mark[vertices] = True
    band = mark[F].any(axis=1)
    for _ in range(int(rings) - 1):
        mark[F[band].reshape(-1)] = True
        band = mark[F].any(axis=1)
    return band


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
        around the seam). Cost grows with the number of tested faces: about
        5–15 ms for the 1,200–1,900 faces within 3 rings of a paper sample's
        seam, 15–70 ms for a whole welded paper sample (5,000–8,000 faces).

    Returns
    -------
    ndarray of int64, shape (p, 2)
        Intersecting face pairs (indices into ``F``), smaller first, sorted.
    """
    import igl.copyleft.cgal as cgal  # compiled CGAL bindings: load on first use

    F = np.asarray(F, dtype=np.int64)
    sel = np.arange(len(F)) if faces is None else np.flatnonzero(np.asarray(faces, dtype=bool))
    if sel.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    sub = F[sel]
    used, local = np.unique(sub, return_inverse=True)
    Vs = np.ascontiguousarray(np.asarray(V, dtype=np.float64)[used])
    Fs = np.ascontiguousarray(local.reshape(-1, 3).astype(np.int64))
    pairs = cgal.remesh_self_intersections(Vs, Fs, detect_only=True)[2]
    pairs = sel[np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs, axis=0) if len(pairs) else pairs


def point_polyline_distance(P: np.ndarray, C: np.ndarray, closed: bool) -> np.ndarray:
    """Distance of each point ``P`` (shape (p, 3)) to the polyline ``C`` (shape (k, 3)).

    Returns shape (p,). Memory is ``p × k``; chunked for long inputs.
    """
    A = C
    B = np.roll(C, -1, axis=0) if closed else C[1:]
    A = A[: len(B)]
    AB = B - A
    ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    out = np.empty(len(P))
    chunk = max(1, 2_000_000 // max(len(A), 1))
    for s in range(0, len(P), chunk):
        Q = P[s : s + chunk]
        t = np.clip(np.einsum("pkj,kj->pk", Q[:, None, :] - A[None], AB) / ab2, 0.0, 1.0)
        D = A[None] + t[..., None] * AB[None] - Q[:, None, :]
        out[s : s + chunk] = np.sqrt(np.einsum("pkj,pkj->pk", D, D).min(axis=1))
    return out


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
    c0 = np.einsum("ij,ij->i", n0[pairs[:, 0]], n0[pairs[:, 1]])
    c1 = np.einsum("ij,ij->i", n1[pairs[:, 0]], n1[pairs[:, 1]])
    return pairs[(c1 < limit) & (c0 >= limit)]


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
