"""Topological checks a mesh must pass before it is joined."""

from __future__ import annotations

import numpy as np

from . import topology
from .errors import MeshError, SolveError
from .mesh import Mesh
from .polyline import polyline_length

__all__ = [
    "MAX_COORDINATE",
    "MAX_SEAM_LENGTH_RATIO",
    "MIN_EDGE_DIGITS",
    "check_coordinates",
    "check_seam_scales",
    "check_surface",
    "check_guest_reaches_seam",
    "relative_area_floor",
]

#: Faces whose area is below this fraction of the mean face area count as zero-area
#: (the one floor: :func:`check_surface`, :func:`igljoin.clean.diagnose` and
#: :func:`igljoin.weld.check_welded` all use it).
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
    # the length of every face side, as np.linalg.norm of its vector (squares summed
    # left to right), on contiguous coordinate rows
    VT = np.ascontiguousarray(np.asarray(mesh.V, dtype=np.float64).T)  # (3, n)
    FT = np.ascontiguousarray(np.asarray(mesh.F, dtype=np.int64).T)  # (3, m)
    P = [np.take(VT, FT[c], axis=1) for c in range(3)]  # (3, m) corners
    sq = [
        (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2] for d in (P[1] - P[0], P[2] - P[1], P[0] - P[2])
    ]
    edge = float(np.median(np.sqrt(np.concatenate(sq))))
    resolution = mag * np.finfo(np.float64).eps
    if edge > 0 and resolution > edge * 10.0**-MIN_EDGE_DIGITS:
        digits = max(0.0, np.log10(edge / resolution)) if resolution > 0 else 16.0
        raise MeshError(
            f"{role}: coordinates of magnitude {mag:.3g} keep only {digits:.1f} significant "
            f"digits of its median edge length {edge:.3g} (float64 has 16 in all); results "
            f"would be rounding noise. Move host and guest by the same offset near the origin "
            "(subtract the host's centroid from both) and join again"
        )


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
        lh = polyline_length(host_V[np.asarray(hc.indices)], bool(hc.closed))
        lg = polyline_length(guest_V[np.asarray(gc.indices)], bool(gc.closed))
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
    count = topology.row_counts(np.sort(F, axis=1), n)
    if (count > 1).any():
        raise MeshError(
            f"{role}: {int((count > 1).sum())} faces are duplicated (same three vertices); {fix}"
        )
    half = topology.half_edges(F, n)
    src, _, _, skey = half
    start, cnt = topology.runs(skey)
    if (cnt > 2).any():
        bad = np.stack(np.divmod(skey[start[cnt > 2]], n), axis=1)
        raise MeshError(
            f"{role}: {len(bad)} edges are shared by more than two faces (non-manifold; first "
            f"{bad[:3].tolist()}); {fix}"
        )
    # every edge has at most two sides and no face repeats a vertex (both checked above)
    dcount = topology.repeated_directed_pairs(half, start[cnt == 2])
    if dcount:
        if not topology.orientable(F):
            raise MeshError(
                f"{role}: the surface is non-orientable (a Möbius-like twist: no choice of face "
                "orientations is consistent), so it has no inside and outside to join; "
                "igljoin clean cannot fix this: remodel the surface or cut it along the twist"
            )
        raise MeshError(
            f"{role}: {dcount} edges are traversed twice in the same direction "
            f"(faces inconsistently oriented); {fix} — it orients faces consistently"
        )
    used = np.zeros(n, dtype=bool)
    used[src] = True
    if role == "guest":
        shared = topology.shared_rows(mesh.V[used])
        if shared.any():
            dup = np.flatnonzero(used)[shared]
            raise MeshError(
                f"guest: {dup.size} vertices share their position with another vertex "
                f"(duplicates, first {_first(dup)}); they split the surface into pieces — {fix}"
            )
    vm = topology.vertex_manifold(F, n, half)
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
