"""Synthetic phantoms reproducing the experiments of the paper (§5, Figs. 2-3).

The paper ("Deformation and Smooth Joining of Mesh Models for Cardiac Surgical
Simulation", GMP 2008) evaluates the join on two surgical scenarios, each with
three samples whose guest boundary is *shorter* than (ratio 0.8), *equal* to
(1.0) and *longer* than (1.25) the host boundary:

``end_to_end`` (the artery rows of the paper's figures, Fig. 2)
    End-to-end anastomosis of two arteries. The rigid host is an artery stump
    (:func:`artery_tube`, radius 4 mm, 30 mm long) whose free end is cut
    obliquely at 30 degrees, so its joined boundary is an ellipse; it occupies
    ``z <= 0`` with the bevelled end at the origin. The flexible guest is a
    straight-cut artery (40 mm long, ~2,436 vertices, 87 points on its end
    circle like the host's 87 ellipse points, i.e. ~174 seam points) whose
    radius makes its end circle 0.8 / 1.0 / 1.25 times as long as the host
    ellipse. It starts in an "initial configuration" like Fig. 2, row 1: its
    joined end 3 mm above the host's, tilted 15 degrees about x and shifted
    1 mm in x.

``partial_patch`` (the patch rows, Fig. 3)
    Partial patching: a flat patch (:func:`flat_patch`, ~1,300 vertices, 203
    boundary points) is sewn into an elliptic hole (203 points) cut in a piece
    of aortic wall (:func:`aortic_wall`, a 120-degree piece of a cylinder of
    radius 15 mm). The patch has the hole's aspect ratio, its perimeter is
    0.8 / 1.0 / 1.25 times the hole's, and it floats 5 mm outside the wall,
    facing outward and turned 10 degrees about its normal.

``open_strip`` (not in the paper; exercises open seams)
    A strip of cylinder wall (host) and a flat rectangular strip (guest) to
    be joined along one long side: an *open* seam whose ends are not closed.

Beyond the paper, :func:`bypass_graft_sample` is an end-to-side coronary
bypass: a graft bevelled at both ends (:func:`cut_tube`; one bevelled end
alone is :func:`bevelled_graft`) to be sewn over elliptic openings in the
aortic wall and in a coronary artery, two seams in one solve; and
:func:`stiff_patch_sample` is the partial patch with a stiffer half.

Conventions shared by every mesh built here: consistently oriented triangles
whose right-hand-rule normals point outward (away from the vessel axis, or
along the wall's outward normal for the flat patch after placement),
edge-manifold, no degenerate faces, no unreferenced vertices, millimetres.
Everything is deterministic for a given ``seed``; ``irregularity`` jitters
interior vertices only, so boundary curves stay exact.

Boundary curves are listed in the *face-induced* direction (the direction of
the faces' directed boundary edges, which is also the order of
``igl.boundary_loop_all(F)``). Index layouts:

* :func:`artery_tube`: ring ``k`` is vertices ``k*n_around ... (k+1)*n_around - 1``
  ordered by increasing angle; ring 0 (the joined end) in that order is the
  face-induced direction, the last ring's face-induced direction is reversed.
* :func:`aortic_wall`: vertices ``0 ... n_hole - 1`` are the hole in
  face-induced order, followed by the outer rectangle, then interior vertices.
* :func:`flat_patch`: vertices ``0 ... n_boundary - 1`` are the boundary in
  face-induced (counter-clockwise about +z) order, then interior vertices.

Examples
--------
>>> from igljoin.phantoms import paper_sample
>>> s = paper_sample("end_to_end", "equal")
>>> s.host_curve.size, round(s.boundary_ratio, 3)
(87, 1.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import igl
import igl.triangle
import numpy as np

from . import topology
from .boundary import Curve, boundary_loops
from .errors import CurveError, MeshError, OptionsError
from .mesh import Mesh
from .polyline import polyline_length

__all__ = [
    "LENGTH_RATIOS",
    "SCENARIOS",
    "Sample",
    "aortic_wall",
    "artery_tube",
    "bevelled_graft",
    "bypass_graft_sample",
    "cut_tube",
    "ellipse_perimeter",
    "ellipse_scale_for_perimeter",
    "flat_patch",
    "paper_sample",
    "paper_samples",
    "polyline_length",
    "tube_end_loop",
]

#: Scenario names accepted by :func:`paper_sample`.
SCENARIOS = ("end_to_end", "partial_patch", "open_strip")

#: Guest / host boundary length ratio of each sample length (paper §5).
LENGTH_RATIOS = {"shorter": 0.8, "equal": 1.0, "longer": 1.25}

#: Largest accepted ``irregularity``: below 0.5 an edge cannot collapse.
MAX_IRREGULARITY = 0.45

# Paper-sized defaults (point counts at resolution 1).
_E2E_N_AROUND = 87
_E2E_HOST_N_ALONG = 20
_E2E_GUEST_N_ALONG = 28
_PATCH_N = 203
_PATCH_TOTAL_VERTICES = 1300
_STRIP_HOST_GRID = (40, 20)  # (along z, around)
_STRIP_GUEST_GRID = (30, 16)  # (along z, across)
_BYPASS_N_HOLE = 56  # points on each opening of the bypass sample
_BYPASS_N_AROUND = 40  # graft vertices per ring
_BYPASS_N_ALONG = 60  # graft rings
_CORONARY_RADIUS = 2.0


# ----------------------------------------------------------------------------
# small geometric helpers
# ----------------------------------------------------------------------------


def ellipse_perimeter(a, b):
    """Perimeter of an ellipse (Ramanujan's second approximation).

    Parameters
    ----------
    a, b : float or array_like
        Semi-axes (broadcast together), non-negative.

    Returns
    -------
    float or numpy.ndarray
        ``pi (a + b) (1 + 3h / (10 + sqrt(4 - 3h)))`` with
        ``h = ((a - b) / (a + b))**2``; relative error below 1e-9 for the
        aspect ratios used here (exact for circles).

    Examples
    --------
    >>> round(float(ellipse_perimeter(1.0, 1.0)), 12) == round(2 * math.pi, 12)
    True
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    s = a + b
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(s > 0, ((a - b) / np.where(s > 0, s, 1.0)) ** 2, 0.0)
    p = np.pi * s * (1.0 + 3.0 * h / (10.0 + np.sqrt(4.0 - 3.0 * h)))
    return float(p) if p.ndim == 0 else p


def ellipse_scale_for_perimeter(a: float, b: float, perimeter: float) -> float:
    """Scale factor ``s`` such that the ellipse ``(s a, s b)`` has a given perimeter.

    Parameters
    ----------
    a, b : float
        Semi-axes of the reference ellipse (not both zero).
    perimeter : float
        Wanted perimeter, > 0.

    Returns
    -------
    float
        ``perimeter / ellipse_perimeter(a, b)`` (the perimeter is homogeneous
        of degree one in the axes).
    """
    p0 = ellipse_perimeter(a, b)
    if not p0 > 0 or not perimeter > 0:
        raise OptionsError(
            f"ellipse_scale_for_perimeter: need positive axes and perimeter, got a={a}, "
            f"b={b}, perimeter={perimeter}"
        )
    return float(perimeter) / float(p0)


def _ellipse_points(a: float, b: float, n: int, *, clockwise: bool = False) -> np.ndarray:
    """``n`` points on the ellipse ``(a cos t, b sin t)`` equally spaced in arc length.

    Starts at ``(a, 0)``; counter-clockwise unless ``clockwise``. Shape (n, 2).
    """
    m = max(64 * n, 8192)
    t = np.linspace(0.0, 2.0 * np.pi, m + 1)
    dense = np.column_stack([a * np.cos(t), b * np.sin(t)])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    tk = np.interp(s[-1] * np.arange(n) / n, s, t)
    sign = -1.0 if clockwise else 1.0
    return np.column_stack([a * np.cos(tk), sign * b * np.sin(tk)])


def _rotation(axis: str, deg: float) -> np.ndarray:
    """3x3 rotation matrix by ``deg`` degrees about coordinate axis ``axis``."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i = "xyz".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    R = np.eye(3)
    R[j, j], R[j, k], R[k, j], R[k, k] = c, -s, s, c
    return R


def _affine(V: np.ndarray, F: np.ndarray, M: np.ndarray, t) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``x -> M x + t``; flip the faces if ``M`` mirrors, so normals keep their side."""
    V2 = V @ M.T + np.asarray(t, dtype=np.float64)
    F2 = F[:, ::-1] if np.linalg.det(M) < 0 else F
    return V2, np.ascontiguousarray(F2)


def _count(base: int, factor: float, minimum: int) -> int:
    """``round(base * factor)``, at least ``minimum``."""
    return max(int(minimum), int(round(base * factor)))


# ----------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------


def _positive(value, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise OptionsError(f"{what} must be a positive number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise OptionsError(f"{what} must be a positive finite number, got {value!r}")
    return v


def _int_at_least(value, lo: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise OptionsError(f"{what} must be an integer >= {lo}, got {value!r}")
    if value < lo:
        raise OptionsError(f"{what} must be >= {lo}, got {value}")
    return int(value)


def _irregularity(value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (0.0 <= v <= MAX_IRREGULARITY):
        raise OptionsError(
            f"irregularity must be in [0, {MAX_IRREGULARITY}] (a fraction of the local edge "
            f"length), got {value!r}"
        )
    return v


# ----------------------------------------------------------------------------
# meshing helpers
# ----------------------------------------------------------------------------


def _grid_faces(n_rows: int, n_cols: int, periodic: bool = False) -> np.ndarray:
    """Faces of a structured grid with alternating diagonals.

    Vertex ``(i, j)`` (row ``i``, column ``j``) has index ``i * n_cols + j``.
    Triangles are counter-clockwise in the ``(column, row)`` parameter plane.
    With ``periodic`` the last column connects back to column 0. Shape (m, 3).
    """
    n_q = n_cols if periodic else n_cols - 1
    i, j = np.meshgrid(np.arange(n_rows - 1), np.arange(n_q), indexing="ij")
    jn = (j + 1) % n_cols
    a, b = i * n_cols + j, i * n_cols + jn
    c, d = (i + 1) * n_cols + jn, (i + 1) * n_cols + j
    even = ((i + j) % 2 == 0)[..., None]
    t1 = np.where(even, np.stack([a, b, c], -1), np.stack([a, b, d], -1))
    t2 = np.where(even, np.stack([a, c, d], -1), np.stack([b, c, d], -1))
    return np.stack([t1, t2], axis=-2).reshape(-1, 3).astype(np.int64)


def _signed_areas(P: np.ndarray, F: np.ndarray, period: float | None = None) -> np.ndarray:
    """Signed areas of triangles ``F`` in the 2-D parameter plane ``P`` (n, 2).

    With ``period`` the first coordinate is periodic (differences are wrapped).
    """
    e1 = P[F[:, 1]] - P[F[:, 0]]
    e2 = P[F[:, 2]] - P[F[:, 0]]
    if period is not None:
        for e in (e1, e2):
            e[:, 0] = (e[:, 0] + 0.5 * period) % period - 0.5 * period
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _safe_displacement(
    P: np.ndarray, F: np.ndarray, D: np.ndarray, period: float | None = None
) -> np.ndarray:
    """Shrink a parameter-plane displacement ``D`` (n, 2) until no triangle folds.

    A triangle is acceptable if it keeps at least a quarter of its original
    area; the displacements of the vertices of unacceptable triangles are
    halved until none remains (deterministic, vectorised per sweep).
    """
    A0 = _signed_areas(P, F, period)
    D = D.copy()
    for _ in range(60):
        bad = _signed_areas(P + D, F, period) < 0.25 * A0
        if not bad.any():
            return D
        D[np.unique(F[bad])] *= 0.5
    return np.zeros_like(D)


def _mean_edge_length(P: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Mean length of the edges incident to each vertex, shape (n,)."""
    E = topology.edges(F)[0]
    L = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1)
    n = P.shape[0]
    total = np.bincount(E.ravel(), weights=np.repeat(L, 2), minlength=n)
    count = np.bincount(E.ravel(), minlength=n)
    return total / np.maximum(count, 1)


def _disc_jitter(
    P: np.ndarray, F: np.ndarray, movable: np.ndarray, irregularity: float, seed: int
) -> np.ndarray:
    """Jitter the ``movable`` vertices of a planar mesh inside discs of radius
    ``irregularity`` x their mean incident edge length, without folding."""
    if irregularity == 0.0:
        return P
    rng = np.random.default_rng(seed)
    n = P.shape[0]
    r = irregularity * _mean_edge_length(P, F) * np.sqrt(rng.uniform(0.0, 1.0, n))
    ang = rng.uniform(0.0, 2.0 * np.pi, n)
    D = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    D[~movable] = 0.0
    return P + _safe_displacement(P, F, D)


def _triangulate(V: np.ndarray, E: np.ndarray, H: np.ndarray, flags: str, what: str):
    """Constrained Delaunay triangulation; input vertices keep their indices.

    Returns ``(V2, F2)`` with counter-clockwise faces and no unreferenced vertex.
    """
    V2, F2, _, _, _ = igl.triangle.triangulate(
        np.ascontiguousarray(V, dtype=np.float64),
        np.ascontiguousarray(E, dtype=np.int64),
        np.ascontiguousarray(H, dtype=np.float64).reshape(-1, 2),
        flags=flags,
    )
    n_in = V.shape[0]
    if (
        V2.shape[0] < n_in
        or not np.array_equal(V2[:n_in], V)
        or F2.shape[0] == 0
        or np.bincount(F2.ravel(), minlength=V2.shape[0]).min() == 0
    ):
        raise MeshError(
            f"{what}: the triangulation of the outline failed (boundary points moved, "
            "unreferenced vertices or no faces); the outline is probably too coarse or "
            "self-intersecting - change the point counts or sizes"
        )
    if (_signed_areas(V2, F2) <= 0).any():
        raise MeshError(f"{what}: the triangulation produced a degenerate or flipped triangle")
    return V2, F2.astype(np.int64)


def _loop_edges(start: int, n: int) -> np.ndarray:
    k = np.arange(n)
    return np.column_stack([start + k, start + (k + 1) % n])


# ----------------------------------------------------------------------------
# the three primitive phantoms
# ----------------------------------------------------------------------------


def artery_tube(
    radius: float = 4.0,
    length: float = 40.0,
    n_around: int = 87,
    n_along: int = 28,
    *,
    bevel_deg: float = 0.0,
    irregularity: float = 0.0,
    seed: int = 0,
    name: str = "artery",
) -> Mesh:
    """An open cylindrical artery around the +z axis, optionally cut obliquely at one end.

    Parameters
    ----------
    radius : float
        Tube radius (mm).
    length : float
        Height of the far (straight) end, ``z = length``.
    n_around : int
        Vertices per ring (>= 3).
    n_along : int
        Number of rings (>= 2).
    bevel_deg : float, keyword-only
        Tilt of the cut at ring 0 about the x axis: ring 0 lies on the plane
        ``z = tan(bevel) y`` through the origin (an ellipse with semi-axes
        ``radius`` and ``radius / cos(bevel)``). Rings interpolate linearly in
        ``z`` from this cut to ``z = length``. ``|bevel_deg| < 90`` and
        ``radius tan|bevel| < length``.
    irregularity : float in [0, 0.45], keyword-only
        Vertices not on ring 0 or the last ring move tangentially (angle and
        ``z``, independently uniform) by up to ``irregularity`` times the local
        edge length in that direction; displacements that would fold a
        triangle are shrunk. The boundary rings stay exact.
    seed : int, keyword-only
        Seed of ``numpy.random.default_rng`` (used only if ``irregularity > 0``).
    name : str, keyword-only
        Mesh name.

    Returns
    -------
    Mesh
        ``n_around * n_along`` vertices and ``2 n_around (n_along - 1)``
        faces; normals point away from the axis; two boundary loops.

    Notes
    -----
    Vertex ``k * n_around + j`` is on ring ``k`` at angle
    ``2 pi j / n_around`` (before jitter). Ring 0 (the joined end) is
    ``arange(n_around)`` and that order is its face-induced boundary
    direction (counter-clockwise about +z); see :func:`tube_end_loop`. The
    last ring's face-induced direction is decreasing ``j``.
    """
    radius = _positive(radius, "artery_tube: radius")
    length = _positive(length, "artery_tube: length")
    n_around = _int_at_least(n_around, 3, "artery_tube: n_around")
    n_along = _int_at_least(n_along, 2, "artery_tube: n_along")
    irregularity = _irregularity(irregularity)
    bevel = math.radians(float(bevel_deg))
    if not abs(bevel_deg) < 90.0 or radius * abs(math.tan(bevel)) >= length:
        raise OptionsError(
            f"artery_tube: bevel_deg={bevel_deg} cuts past the far end (need |bevel| < 90 "
            f"and radius*tan|bevel| < length = {length}); reduce the bevel or lengthen the tube"
        )
    theta = 2.0 * np.pi * np.arange(n_around) / n_around
    z0 = math.tan(bevel) * radius * np.sin(theta)  # (n_around,) ring-0 heights
    t = np.arange(n_along) / (n_along - 1)
    U = np.broadcast_to(radius * theta, (n_along, n_around)).copy()  # arc-length coordinate
    Z = z0[None, :] + (length - z0)[None, :] * t[:, None]
    F = _grid_faces(n_along, n_around, periodic=True)
    if irregularity > 0.0 and n_along > 2:
        rng = np.random.default_rng(seed)
        h_u = 2.0 * np.pi * radius / n_around
        h_v = (length - z0) / (n_along - 1)
        D = np.stack(
            [
                rng.uniform(-1.0, 1.0, (n_along, n_around)) * irregularity * h_u,
                rng.uniform(-1.0, 1.0, (n_along, n_around)) * irregularity * h_v[None, :],
            ],
            axis=-1,
        )
        D[[0, -1]] = 0.0
        P = np.column_stack([U.ravel(), Z.ravel()])
        D = _safe_displacement(P, F, D.reshape(-1, 2), period=2.0 * np.pi * radius)
        U = U + D[:, 0].reshape(U.shape)
        Z = Z + D[:, 1].reshape(Z.shape)
    phi = U / radius
    V = np.column_stack([(radius * np.cos(phi)).ravel(), (radius * np.sin(phi)).ravel(), Z.ravel()])
    return Mesh(V, F, name=name)


def tube_end_loop(mesh_or_n_around) -> np.ndarray:
    """Vertex indices of ring 0 (the joined end) of an :func:`artery_tube`.

    Parameters
    ----------
    mesh_or_n_around : Mesh or int
        A tube built by :func:`artery_tube` (possibly moved rigidly), or its
        ``n_around``.

    Returns
    -------
    numpy.ndarray of int64, shape (n_around,)
        ``arange(n_around)``, which is ring 0 in its face-induced boundary
        direction. For a mesh, the boundary loop through vertex 0 (rotated to
        start at 0), which equals ``arange(n_around)`` for a tube.
    """
    if isinstance(mesh_or_n_around, Mesh):
        for loop in igl.boundary_loop_all(mesh_or_n_around.F):
            loop = np.asarray(loop, dtype=np.int64)
            hit = np.flatnonzero(loop == 0)
            if hit.size:
                return np.roll(loop, -int(hit[0]))
        raise CurveError(
            f"tube_end_loop: vertex 0 of {mesh_or_n_around.name!r} is not on a boundary loop; "
            "pass a mesh built by artery_tube (ring 0 = vertices 0..n_around-1)"
        )
    return np.arange(_int_at_least(mesh_or_n_around, 3, "tube_end_loop: n_around"), dtype=np.int64)


def aortic_wall(
    radius: float = 15.0,
    height: float = 40.0,
    arc_deg: float = 120.0,
    hole_axes: tuple[float, float] = (8.0, 5.0),
    n_hole: int = 203,
    *,
    target_edge: float | None = None,
    irregularity: float = 0.0,
    seed: int = 0,
    name: str = "aortic wall",
    full_turn: bool = False,
) -> Mesh:
    """A piece of aortic wall (cylinder around the z axis) with an elliptic hole.

    Parameters
    ----------
    radius : float
        Cylinder radius (mm).
    height : float
        The piece spans ``z`` in ``[-height/2, height/2]``.
    arc_deg : float
        Angular width in (0, 360): angles ``[-arc/2, arc/2]`` around +x.
    hole_axes : (float, float)
        Semi-axes of the elliptic hole, ``(along z, along the circumference)``,
        measured in the unrolled wall; centred at angle 0, ``z = 0``.
    n_hole : int
        Points on the hole (>= 8), equally spaced in arc length along the
        unrolled ellipse.
    target_edge : float, optional, keyword-only
        Edge length far from the hole and along the outer rectangle (mm).
        Default: 7.5 x the hole's point spacing (1.53 mm at the defaults).
        Near the hole the edges are about the hole spacing; Triangle's
        quality bound (30 degrees) grades the size in between.
    irregularity : float in [0, 0.45], keyword-only
        Interior vertices move in the wall by up to ``irregularity`` x their
        mean incident edge length (never folding a triangle); both boundaries
        stay exact.
    seed : int, keyword-only
        Seed of ``numpy.random.default_rng``.
    name : str, keyword-only
        Mesh name.
    full_turn : bool, keyword-only
        Close the wall all the way round (``arc_deg`` is then ignored): a
        vessel with a side opening, three boundary loops (both ends and the
        opening). Used for the coronary artery of the bypass-graft phantom.

    Returns
    -------
    Mesh
        About 1,460 vertices at the defaults; normals point away from the
        axis (+x at the hole centre); two boundary loops.

    Notes
    -----
    Built in unrolled coordinates ``(u, v) = (radius * angle, z)`` with
    ``igl.triangle.triangulate`` (no Steiner points on the boundary) and then
    wrapped onto the cylinder. Vertices ``0 ... n_hole - 1`` are the hole,
    listed in its face-induced direction (clockwise seen from outside,
    starting at angle ``hole_axes[1] / radius``, ``z = 0``); the next vertices
    are the outer rectangle in its face-induced direction (counter-clockwise
    seen from outside, starting at the corner ``(-arc/2, -height/2)``); then
    the interior.
    """
    radius = _positive(radius, "aortic_wall: radius")
    height = _positive(height, "aortic_wall: height")
    arc = 360.0 if full_turn else _positive(arc_deg, "aortic_wall: arc_deg")
    if arc >= 360.0 and not full_turn:
        raise OptionsError(f"aortic_wall: arc_deg must be below 360, got {arc_deg}")
    a_v = _positive(hole_axes[0], "aortic_wall: hole_axes[0]")
    a_u = _positive(hole_axes[1], "aortic_wall: hole_axes[1]")
    n_hole = _int_at_least(n_hole, 8, "aortic_wall: n_hole")
    irregularity = _irregularity(irregularity)
    half_u = 0.5 * radius * math.radians(arc)
    half_v = 0.5 * height
    hole_len = float(ellipse_perimeter(a_u, a_v))
    h_hole = hole_len / n_hole
    if target_edge is None:
        far = 7.5 * h_hole
    else:
        far = _positive(target_edge, "aortic_wall: target_edge")
    if a_u + h_hole >= half_u or a_v + h_hole >= half_v:
        raise OptionsError(
            f"aortic_wall: the hole (semi-axes {hole_axes}) does not fit in the wall "
            f"(half-extents {half_v:.3g} along z, {half_u:.3g} around); enlarge the wall "
            "or shrink the hole"
        )
    hole = _ellipse_points(a_u, a_v, n_hole, clockwise=True)
    n_u = max(2, math.ceil(2.0 * half_u / far))
    n_v = max(2, math.ceil(2.0 * half_v / far))
    su = np.linspace(-half_u, half_u, n_u + 1)[:-1]
    sv = np.linspace(-half_v, half_v, n_v + 1)[:-1]
    rect = np.concatenate(
        [
            np.column_stack([su, np.full(n_u, -half_v)]),
            np.column_stack([np.full(n_v, half_u), sv]),
            np.column_stack([-su, np.full(n_u, half_v)]),
            np.column_stack([np.full(n_v, -half_u), -sv]),
        ]
    )
    n_rect = rect.shape[0]
    P_in = np.concatenate([hole, rect])
    E = np.concatenate([_loop_edges(0, n_hole), _loop_edges(n_hole, n_rect)])
    max_area = math.sqrt(3.0) / 4.0 * far**2
    P, F = _triangulate(P_in, E, np.zeros((1, 2)), f"pq30a{max_area:.10f}YQ", "aortic_wall")
    movable = np.arange(P.shape[0]) >= P_in.shape[0]
    P = _disc_jitter(P, F, movable, irregularity, seed)
    if full_turn:
        P, F = _close_seam(P, F, half_u)
    phi = P[:, 0] / radius
    V = np.column_stack([radius * np.cos(phi), radius * np.sin(phi), P[:, 1]])
    return Mesh(V, F, name=name)


def _close_seam(P: np.ndarray, F: np.ndarray, half_u: float) -> tuple[np.ndarray, np.ndarray]:
    """Glue the ``u = +half_u`` side of an unrolled wall onto its ``u = -half_u`` side.

    Both sides carry the same ``v`` samples (no Steiner points on the
    boundary), so each right-side vertex has a left-side twin. Returns the
    vertices without the right side, shape (n', 2), and the re-indexed faces.
    """
    tol = 1e-9 * half_u
    right = np.flatnonzero(np.abs(P[:, 0] - half_u) <= tol)
    left = np.flatnonzero(np.abs(P[:, 0] + half_u) <= tol)
    order = np.argsort(P[left, 1])
    v_left = P[left[order], 1]
    # the nearest left-side sample: ``linspace`` rounds the two sides' ``v`` differently in
    # the last bit, so the insertion point may be one past the twin
    pos = np.clip(np.searchsorted(v_left, P[right, 1]), 1, len(left) - 1)
    below = np.abs(v_left[pos - 1] - P[right, 1]) <= np.abs(v_left[pos] - P[right, 1])
    twin = left[order][np.where(below, pos - 1, pos)]
    if not np.allclose(P[twin, 1], P[right, 1], atol=tol):
        raise MeshError("aortic_wall: the two sides of a full-turn wall do not match")
    remap = np.arange(len(P))
    remap[right] = twin
    keep = np.ones(len(P), dtype=bool)
    keep[right] = False
    new_id = np.cumsum(keep) - 1
    return P[keep], new_id[remap[F]]


def flat_patch(
    axes: tuple[float, float] = (8.0, 5.0),
    n_boundary: int = 203,
    *,
    n_interior_target: int | None = None,
    irregularity: float = 0.0,
    seed: int = 0,
    name: str = "patch",
) -> Mesh:
    """A flat elliptic patch in the ``z = 0`` plane with normal +z.

    Parameters
    ----------
    axes : (float, float)
        Semi-axes along x and y (mm).
    n_boundary : int
        Boundary points (>= 8), equally spaced in arc length, counter-clockwise
        from ``(axes[0], 0, 0)``.
    n_interior_target : int, optional, keyword-only
        Wanted number of interior vertices; the maximum triangle area is
        calibrated (a few deterministic Triangle runs) to land within a few
        percent. Default ``round(1097 (n_boundary / 203)**2)``, i.e. about
        1,300 vertices in all at 203 boundary points like the paper's patch;
        the count does not depend on the patch size.
    irregularity : float in [0, 0.45], keyword-only
        Interior vertices move in the plane by up to ``irregularity`` x their
        mean incident edge length (never folding a triangle).
    seed : int, keyword-only
        Seed of ``numpy.random.default_rng``.
    name : str, keyword-only
        Mesh name.

    Returns
    -------
    Mesh
        One boundary loop, vertices ``0 ... n_boundary - 1`` in face-induced
        order; interior vertices follow.

    Notes
    -----
    Interior triangles are somewhat larger than the boundary spacing at the
    defaults (edges ~0.33 mm against 0.20 mm on the boundary): equilateral
    triangles of the boundary spacing would need ~3,500 vertices, while the
    paper's patch has ~1,300.
    """
    a = _positive(axes[0], "flat_patch: axes[0]")
    b = _positive(axes[1], "flat_patch: axes[1]")
    n_boundary = _int_at_least(n_boundary, 8, "flat_patch: n_boundary")
    irregularity = _irregularity(irregularity)
    if n_interior_target is None:
        n_interior_target = _default_patch_interior(n_boundary)
    n_target = _int_at_least(n_interior_target, 0, "flat_patch: n_interior_target")
    P_in = _ellipse_points(a, b, n_boundary)
    E = _loop_edges(0, n_boundary)
    H = np.zeros((0, 2))
    if n_target == 0:
        P, F = _triangulate(P_in, E, H, "pq30YQ", "flat_patch")
    else:
        area = np.pi * a * b / (2 * n_target + n_boundary)
        for _ in range(6):
            P, F = _triangulate(P_in, E, H, f"pq30a{area:.12g}YQ", "flat_patch")
            got = max(P.shape[0] - n_boundary, 1)
            if abs(got - n_target) <= 0.02 * n_target:
                break
            area *= got / n_target
    movable = np.arange(P.shape[0]) >= n_boundary
    P = _disc_jitter(P, F, movable, irregularity, seed)
    V = np.column_stack([P, np.zeros(P.shape[0])])
    return Mesh(V, F, name=name)


def _default_patch_interior(n_boundary: int) -> int:
    """Interior vertex count giving ~1,300 vertices at 203 boundary points (scales as n^2)."""
    return int(round((_PATCH_TOTAL_VERTICES - _PATCH_N) * (n_boundary / _PATCH_N) ** 2))


def _structured_sheet(
    u: np.ndarray, v: np.ndarray, irregularity: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """A planar grid over ``u`` (columns) x ``v`` (rows), jittered inside.

    Returns ``(P, F)``: P (len(v) * len(u), 2) with vertex ``i * len(u) + j`` at
    ``(u[j], v[i])``; faces counter-clockwise in ``(u, v)``.
    """
    Uu, Vv = np.meshgrid(u, v)
    P = np.column_stack([Uu.ravel(), Vv.ravel()])
    F = _grid_faces(v.size, u.size)
    movable = np.zeros((v.size, u.size), dtype=bool)
    movable[1:-1, 1:-1] = True
    return _disc_jitter(P, F, movable.ravel(), irregularity, seed), F


# ----------------------------------------------------------------------------
# the paper's samples
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Sample:
    """One host/guest pair to join.

    Attributes
    ----------
    name : str
        ``"<scenario>/<length>"``, e.g. ``"end_to_end/equal"``.
    scenario : str
        ``"end_to_end"``, ``"partial_patch"`` or ``"open_strip"``.
    length : str
        ``"shorter"``, ``"equal"`` or ``"longer"``.
    host : Mesh
        The rigid mesh.
    guest : Mesh
        The flexible mesh to deform.
    host_curve : numpy.ndarray of int64, shape (k,)
        Ordered host boundary vertices of the seam, in the host's
        face-induced boundary direction (closed loop, or an open path of a
        loop).
    guest_curve : numpy.ndarray of int64, shape (k',), Curve, or None
        Ordered guest seam vertices, starting at the end geometrically
        matching ``host_curve[0]`` (open seams); for closed seams a
        :class:`igljoin.Curve` naming the loop (several loops) or ``None``
        (one loop), so that the joining code finds the start itself.
    closed : bool
        Whether the seam is a closed loop.
    boundary_ratio : float
        Measured polyline length of the guest seam curve over the host's.
    description : str
        One-paragraph human description.
    """

    name: str
    scenario: str
    length: str
    host: Mesh
    guest: Mesh
    host_curve: np.ndarray
    guest_curve: np.ndarray | Curve | None
    closed: bool
    boundary_ratio: float
    description: str

    def __post_init__(self) -> None:
        for field_name in ("host_curve", "guest_curve"):
            value = getattr(self, field_name)
            if value is None or isinstance(value, Curve):
                continue
            arr = np.array(value, dtype=np.int64, copy=True)
            arr.flags.writeable = False
            object.__setattr__(self, field_name, arr)


def _loop_through(F: np.ndarray, vertex: int) -> int:
    """Index (as listed by :func:`igljoin.boundary_loops`) of the loop through ``vertex``."""
    return next(k for k, lp in enumerate(boundary_loops(F)) if vertex in lp)


def _sample(
    scenario: str,
    label: str,
    host: Mesh,
    guest: Mesh,
    host_curve: np.ndarray,
    guest_curve: np.ndarray | Curve | None,
    guest_points: np.ndarray,
    closed: bool,
    description: str,
) -> Sample:
    """A :class:`Sample` of ``scenario``, its boundary ratio measured on the built meshes.

    ``guest_points`` (shape (k', 3)) are the guest seam curve's positions in
    order; the ratio is their polyline length over the host curve's.
    """
    ratio = polyline_length(guest_points, closed) / polyline_length(host.V[host_curve], closed)
    return Sample(
        name=f"{scenario}/{label}",
        scenario=scenario,
        length=label,
        host=host,
        guest=guest,
        host_curve=host_curve,
        guest_curve=guest_curve,
        closed=closed,
        boundary_ratio=ratio,
        description=description,
    )


def _end_to_end(ratio, label, res, gres, irregularity, seed) -> Sample:
    n_h = _count(_E2E_N_AROUND, res, 8)
    tube = artery_tube(
        4.0,
        30.0,
        n_h,
        _count(_E2E_HOST_N_ALONG, res, 2),
        bevel_deg=30.0,
        irregularity=irregularity,
        seed=seed,
    )
    # Turn the stump half a turn about x: it runs from its bevelled ring 0 at
    # the origin towards -z and ring 0 still lies on z = tan(30) y. A rotation
    # keeps the outward normals (_affine would flip F for a mirror).
    hV, hF = _affine(tube.V, tube.F, _rotation("x", 180.0), (0.0, 0.0, 0.0))
    host = Mesh(hV, hF, name="host artery")
    host_curve = np.arange(n_h, dtype=np.int64)
    L_host = polyline_length(host.V[host_curve])
    n_g = _count(_E2E_N_AROUND, res * gres, 8)
    r_g = ratio * L_host / (2.0 * n_g * math.sin(math.pi / n_g))  # regular n_g-gon perimeter
    g = artery_tube(
        r_g,
        40.0,
        n_g,
        _count(_E2E_GUEST_N_ALONG, res * gres, 2),
        irregularity=irregularity,
        seed=seed + 1,
    )
    gV, gF = _affine(g.V, g.F, _rotation("x", 15.0), (1.0, 0.0, 3.0))
    guest = Mesh(gV, gF, name="guest artery")
    return _sample(
        "end_to_end",
        label,
        host,
        guest,
        host_curve,
        Curve(loop=_loop_through(guest.F, 0)),
        guest.V[:n_g],
        True,
        (
            "End-to-end anastomosis: a rigid artery stump (radius 4 mm, z <= 0) cut at 30 "
            f"degrees, and a straight artery (radius {r_g:.3f} mm) whose end circle is "
            f"{ratio:g} x the stump's elliptic end, starting 3 mm above it, tilted 15 degrees "
            "about x and shifted 1 mm in x (paper Fig. 2, initial configuration)."
        ),
    )


def _partial_patch(ratio, label, res, gres, irregularity, seed) -> Sample:
    radius, hole_axes = 15.0, (8.0, 5.0)
    n_hole = _count(_PATCH_N, res, 8)
    host = aortic_wall(
        radius,
        hole_axes=hole_axes,
        n_hole=n_hole,
        irregularity=irregularity,
        seed=seed,
        name="host aortic wall",
    )
    host_curve = np.arange(n_hole, dtype=np.int64)
    L_host = polyline_length(host.V[host_curve])
    n_b = _count(_PATCH_N, res * gres, 8)
    # Equal-arc-length points scale linearly with the axes, so one measurement
    # of the unit polyline gives the exact scale.
    s = ratio * L_host / polyline_length(_ellipse_points(hole_axes[0], hole_axes[1], n_b))
    p = flat_patch(
        (s * hole_axes[0], s * hole_axes[1]),
        n_b,
        n_interior_target=_default_patch_interior(n_b),
        irregularity=irregularity,
        seed=seed + 1,
    )
    # local x (long axis) -> world z, local z (normal) -> world +x: proper rotation.
    M = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]) @ _rotation("z", 10.0)
    gV, gF = _affine(p.V, p.F, M, (radius + 5.0, 0.0, 0.0))
    guest = Mesh(gV, gF, name="guest patch")
    return _sample(
        "partial_patch",
        label,
        host,
        guest,
        host_curve,
        None,
        guest.V[:n_b],
        True,
        (
            "Partial patching: a rigid 120-degree piece of aortic wall (radius 15 mm) with an "
            f"elliptic 16 x 10 mm hole, and a flat elliptic patch whose perimeter is {ratio:g} x "
            "the hole's, 5 mm outside the wall, facing outward, turned 10 degrees about its "
            "normal (paper Fig. 3)."
        ),
    )


def _open_strip(ratio, label, res, gres, irregularity, seed) -> Sample:
    radius, arc_deg, span, gap, tilt, width = 15.0, 40.0, 30.0, 2.0, 20.0, 12.0
    n_z, n_phi = (_count(k, res, 3) for k in _STRIP_HOST_GRID)
    P, hF = _structured_sheet(
        radius * np.radians(np.linspace(0.0, arc_deg, n_phi)),
        np.linspace(0.0, span, n_z),
        irregularity,
        seed,
    )
    phi = P[:, 0] / radius
    host = Mesh(
        np.column_stack([radius * np.cos(phi), radius * np.sin(phi), P[:, 1]]),
        hF,
        name="host wall strip",
    )
    host_curve = np.arange(n_z, dtype=np.int64) * n_phi + (n_phi - 1)
    g_z, g_s = (_count(k, res * gres, 3) for k in _STRIP_GUEST_GRID)
    half = 0.5 * span * ratio
    Q, gF = _structured_sheet(
        np.linspace(0.0, width, g_s),
        np.linspace(0.5 * span - half, 0.5 * span + half, g_z),
        irregularity,
        seed + 1,
    )
    a = math.radians(arc_deg)
    normal = np.array([math.cos(a), math.sin(a), 0.0])  # host outward normal at the side
    tangent = np.array([-math.sin(a), math.cos(a), 0.0])  # leaves the host side
    d = math.cos(math.radians(tilt)) * tangent + math.sin(math.radians(tilt)) * normal
    base = radius * normal + gap * d
    # (s, z) -> base + s d + z e_z; d x e_z is the guest normal (outward-ish, like the host's).
    M = np.column_stack([d, [0.0, 0.0, 1.0], np.cross(d, [0.0, 0.0, 1.0])])
    gV, gF = _affine(np.column_stack([Q, np.zeros(Q.shape[0])]), gF, M, base)
    guest = Mesh(gV, gF, name="guest flat strip")
    guest_curve = np.arange(g_z, dtype=np.int64) * g_s
    return _sample(
        "open_strip",
        label,
        host,
        guest,
        host_curve,
        guest_curve,
        guest.V[guest_curve],
        False,
        (
            "Open seam: a rigid strip of cylinder wall (radius 15 mm, 0-40 degrees, z 0-30 mm) "
            f"and a flat 12 mm wide strip whose joined side is {ratio:g} x the host side at 40 "
            "degrees, leaving it 2 mm away, tilted 20 degrees outward from the tangent."
        ),
    )


_BUILDERS = {"end_to_end": _end_to_end, "partial_patch": _partial_patch, "open_strip": _open_strip}


def paper_sample(
    scenario: str,
    length: str,
    *,
    resolution: float = 1.0,
    guest_resolution: float = 1.0,
    irregularity: float = 0.0,
    seed: int = 0,
) -> Sample:
    """Build one of the paper's samples (or the extra open-seam sample).

    Parameters
    ----------
    scenario : {"end_to_end", "partial_patch", "open_strip"}
        See the module docstring.
    length : {"shorter", "equal", "longer"}
        Guest / host seam length ratio 0.8, 1.0 or 1.25 (measured on the
        polylines, matched to floating-point precision).
    resolution : float, keyword-only
        Scales the number of points along every curve of host and guest
        (0.5 gives about half the points per curve, so about a quarter of the
        vertices).
    guest_resolution : float, keyword-only
        Additional factor for the guest only (0.2 gives a guest about 5 x
        coarser than the host along its seam curve).
    irregularity : float in [0, 0.45], keyword-only
        Jitter of interior vertices of both meshes (see :func:`artery_tube`);
        seam curves stay exact.
    seed : int, keyword-only
        The host uses ``seed``, the guest ``seed + 1``.

    Returns
    -------
    Sample
        At resolution 1: end-to-end host 1,740 vertices / 87 seam points,
        guest 2,436 vertices / 87 seam points; patch host ~1,460 vertices /
        203 seam points, guest ~1,300 vertices / 203 seam points; open strip
        host 20 x 40 grid, guest 16 x 30 grid.
    """
    if scenario not in _BUILDERS:
        raise OptionsError(f"paper_sample: scenario must be one of {SCENARIOS}, got {scenario!r}")
    if length not in LENGTH_RATIOS:
        raise OptionsError(
            f"paper_sample: length must be one of {tuple(LENGTH_RATIOS)}, got {length!r}"
        )
    res = _positive(resolution, "paper_sample: resolution")
    gres = _positive(guest_resolution, "paper_sample: guest_resolution")
    irregularity = _irregularity(irregularity)
    seed = _int_at_least(seed, 0, "paper_sample: seed")
    return _BUILDERS[scenario](LENGTH_RATIOS[length], length, res, gres, irregularity, seed)


def paper_samples(**kw) -> list[Sample]:
    """The paper's six samples: end-to-end then partial patch, each shorter/equal/longer.

    Parameters
    ----------
    **kw
        Keyword arguments of :func:`paper_sample` (``resolution``,
        ``guest_resolution``, ``irregularity``, ``seed``).

    Returns
    -------
    list of Sample
        Six samples.
    """
    return [
        paper_sample(scenario, length, **kw)
        for scenario in ("end_to_end", "partial_patch")
        for length in ("shorter", "equal", "longer")
    ]


# -- several seams and stiffness maps ------------------------------------------------------


def _bezier(P: np.ndarray, n: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (
        (1 - t) ** 3 * P[0] + 3 * (1 - t) ** 2 * t * P[1] + 3 * (1 - t) * t**2 * P[2] + t**3 * P[3]
    )


@dataclass(frozen=True, eq=False)
class MultiSeamSample:
    """A guest joined along several seams (e.g. a bypass graft sewn at both ends).

    Attributes
    ----------
    name : str
    hosts : list of Mesh
        The rigid meshes (one per seam here).
    guest : Mesh
    seams : list of (int, ndarray, Curve)
        ``(host index, host curve, guest curve)`` per seam; host curves are
        ordered host loop vertices, guest curves name a guest loop.
    description : str
    """

    name: str
    hosts: list
    guest: Mesh
    seams: list
    description: str


def _plane_crossings(s_grid, G, point, normal, near):
    """Per generator, the arc length where it crosses a plane, the crossing nearest ``near``.

    ``G`` (len(s_grid), n, 3) are the generators sampled at ``s_grid``; linear between samples.
    """
    f = (G - point) @ normal  # (k, n)
    change = np.sign(f[:-1]) != np.sign(f[1:])
    s_mid = 0.5 * (s_grid[:-1] + s_grid[1:])
    dist = np.where(change, np.abs(s_mid[:, None] - near), np.inf)
    i = np.argmin(dist, axis=0)
    if not np.isfinite(dist[i, np.arange(f.shape[1])]).all():
        raise OptionsError(
            "the cut plane misses the graft: it must cross every generator of the tube near its "
            "end; lengthen the graft or make the bevel less oblique"
        )
    j = np.arange(f.shape[1])
    f0, f1 = f[i, j], f[i + 1, j]
    return s_grid[i] + (s_grid[i + 1] - s_grid[i]) * f0 / (f0 - f1)


def cut_tube(
    centerline: np.ndarray,
    radius: float,
    n_around: int,
    n_along: int,
    cuts: tuple,
    *,
    binormal=(0.0, 1.0, 0.0),
    name: str = "graft",
) -> Mesh:
    """A tube swept along a planar centre line, each end cut by a plane (a bevelled end).

    Parameters
    ----------
    centerline : ndarray, shape (k, 3)
        Densely sampled centre line (``k >= 2``) in a plane whose normal is
        ``binormal``. It is continued straight along its end tangents, so a
        cut plane may lie beyond either end.
    radius : float
    n_around : int
        Vertices per ring (>= 3).
    n_along : int
        Rings (>= 2).
    cuts : ((point, normal), (point, normal))
        The planes that cut the start and the end: each generator of the tube
        (a line at fixed angle round the centre line) runs from where it
        crosses the first plane to where it crosses the second, its ``n_along``
        vertices equally spaced between. A plane oblique to the centre line
        gives an elliptic, bevelled end.
    binormal : array_like, shape (3,), keyword-only
        Unit normal of the centre line's plane; angle 0 round the centre line
        is ``binormal x tangent``.
    name : str, keyword-only

    Returns
    -------
    Mesh
        Vertex ``i * n_around + j`` is on ring ``i``, generator ``j``; rings 0
        and ``n_along - 1`` lie on the two cut planes; normals point away from
        the centre line.
    """
    radius = _positive(radius, "cut_tube: radius")
    n_around = _int_at_least(n_around, 3, "cut_tube: n_around")
    n_along = _int_at_least(n_along, 2, "cut_tube: n_along")
    C = np.asarray(centerline, dtype=np.float64)
    if C.ndim != 2 or C.shape[1] != 3 or len(C) < 2:
        raise OptionsError(f"cut_tube: centerline must have shape (k >= 2, 3), got {C.shape}")
    B = np.asarray(binormal, dtype=np.float64)
    B = B / np.linalg.norm(B)
    seg = np.linalg.norm(np.diff(C, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    T = np.gradient(C, s, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    if np.abs(T @ B).max() > 1e-6:
        raise OptionsError("cut_tube: the centre line must lie in a plane normal to binormal")
    N = np.cross(B, T)
    theta = 2.0 * np.pi * np.arange(n_around) / n_around
    length = float(s[-1])
    reach = length + 4.0 * radius

    def frame(q):
        """Centre and angle-0 direction at arc lengths ``q``, continued straight beyond the ends."""
        q = np.asarray(q, dtype=np.float64)
        c = np.stack([np.interp(q, s, C[:, d]) for d in range(3)], axis=-1)
        n = np.stack([np.interp(q, s, N[:, d]) for d in range(3)], axis=-1)
        c = (
            c
            + np.minimum(q, 0.0)[..., None] * T[0]
            + np.maximum(q - length, 0.0)[..., None] * T[-1]
        )
        return c, n / np.linalg.norm(n, axis=-1, keepdims=True)

    def generators(q):
        c, n = frame(q)
        ring = np.cos(theta)[..., :, None] * n[..., None, :] + np.sin(theta)[:, None] * B
        return c[..., None, :] + radius * ring

    grid = np.linspace(-reach, length + reach, 8 * (len(C) + 64))
    G = generators(grid)
    ends = []
    for (point, normal), near in zip(cuts, (0.0, length)):
        m = np.asarray(normal, dtype=np.float64)
        ends.append(_plane_crossings(grid, G, np.asarray(point, dtype=np.float64), m, near))
    s0, s1 = ends
    if (s1 <= s0).any():
        raise OptionsError("cut_tube: the two cut planes cross inside the tube; move them apart")
    t = np.linspace(0.0, 1.0, n_along)[:, None]
    Q = s0[None, :] + (s1 - s0)[None, :] * t  # (n_along, n_around)
    c, n = frame(Q)
    ring = np.cos(theta)[None, :, None] * n + np.sin(theta)[None, :, None] * B
    V = (c + radius * ring).reshape(-1, 3)
    F = _grid_faces(n_along, n_around, periodic=True)
    normal = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    if np.einsum("ij,ij->i", normal, ring.reshape(-1, 3)[F[:, 0]]).mean() < 0:
        F = F[:, ::-1].copy()
    return Mesh(V, F, name=name)


def bevelled_graft(
    radius: float = 2.0,
    length: float = 20.0,
    bevel_deg: float = 45.0,
    n_around: int = 40,
    n_along: int = 40,
    *,
    name: str = "graft",
) -> Mesh:
    """A straight graft along +z whose end at the origin is cut obliquely (the hood).

    Parameters
    ----------
    radius : float
    length : float
        Distance along the axis from the centre of the bevelled end to the
        square far end ``z = length``.
    bevel_deg : float
        Angle between the cut plane and the axis, in (0, 90]; 90 is a square
        cut. The cut plane contains the x axis; its normal is
        ``(0, -cos b, sin b)``.
    n_around, n_along : int
    name : str, keyword-only

    Returns
    -------
    Mesh
        Ring 0 is the bevelled end, an ellipse of semi-axes ``radius`` (along
        x) and ``radius / sin(bevel)``. Laid on a wall in the cut plane, the
        graft leaves it at ``bevel`` at the **toe** (``y < 0``: the wall and the
        graft meet at an obtuse angle, the graft leaving at ``bevel`` from the
        wall continued across the opening) and at ``180° - bevel`` at the
        **heel** (``y > 0``: an acute angle ``bevel`` between graft and wall).

    Examples
    --------
    >>> g = bevelled_graft(2.0, 20.0, 30.0, 24, 12)
    >>> round(float(np.linalg.norm(g.V[:24], axis=1).max()), 6)  # long semi-axis: r / sin 30°
    4.0
    """
    length = _positive(length, "bevelled_graft: length")
    b = _positive(bevel_deg, "bevelled_graft: bevel_deg")
    if b > 90.0:
        raise OptionsError(f"bevelled_graft: bevel_deg must be in (0, 90], got {bevel_deg}")
    radius = _positive(radius, "bevelled_graft: radius")
    if radius / math.tan(math.radians(b)) >= length:
        raise OptionsError(
            f"bevelled_graft: the bevel reaches past the far end (radius / tan(bevel) = "
            f"{radius / math.tan(math.radians(b)):.3g} >= length {length}); lengthen the graft "
            "or make the bevel less oblique"
        )
    z = np.linspace(0.0, length, 64)
    C = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    m = np.array([0.0, -math.cos(math.radians(b)), math.sin(math.radians(b))])
    cuts = ((np.zeros(3), m), (np.array([0.0, 0.0, length]), np.array([0.0, 0.0, 1.0])))
    return cut_tube(C, radius, n_around, n_along, cuts, binormal=(1.0, 0.0, 0.0), name=name)


def bypass_graft_sample(
    *,
    bevel_deg: float = 45.0,
    hood: float = 1.5,
    radius: float = 2.0,
    gap: float = 1.0,
    resolution: float = 1.0,
) -> MultiSeamSample:
    """A coronary bypass graft sewn end-to-side to the aorta and to a coronary artery.

    The host is two meshes: a piece of aortic wall (radius 15 mm) and a
    coronary artery (radius 2 mm), each with an elliptic opening (the
    arteriotomy) elongated along its vessel. The guest is a graft tube
    (:func:`cut_tube`) swept along a cubic curve from the aorta to the
    coronary, both ends **bevelled**: each is cut by the tangent plane of
    its wall, and the graft leaves each wall at ``bevel_deg`` towards
    ``-z`` (down the aorta, downstream along the coronary artery), so its
    toe points that way and its heel, the acute side, the other way.
    Each opening is the graft's oblique section lengthened and widened by
    ``hood``: the bevelled end spreads over it into a hood, as a surgeon
    sews it. The graft lies ``gap`` short of both walls, so both seams are
    pulled into place.

    Parameters
    ----------
    bevel_deg : float, keyword-only
        Angle between the graft and each wall (the bevel of both ends), in
        (0, 90].
    hood : float, keyword-only
        Millimetres by which each opening's semi-axes exceed the graft's
        oblique section (``radius`` across, ``radius / sin(bevel)`` along),
        >= 0. With 0 the opening is the graft's own end: a hood cannot form,
        and a join angle well below the bevel pinches the graft into itself.
    radius : float, keyword-only
        Graft radius (mm).
    gap : float, keyword-only
        Distance of the graft's ends from their walls (mm), >= 0.
    resolution : float, keyword-only
        Point-count scale.

    Returns
    -------
    MultiSeamSample
        ``seams[0]`` is the aorta, ``seams[1]`` the coronary artery.

    Examples
    --------
    >>> import igljoin
    >>> g = bypass_graft_sample()
    >>> res = igljoin.join(g.hosts, g.guest, seams=g.seams, join_angle=45)
    >>> [abs(float(sm.crease.mean()) - 45.0) < 2.0 for sm in res.seams]
    [True, True]
    >>> res.metrics["self_intersections"]["pairs"], res.metrics["folded_pairs"]
    (0, 0)
    """
    b = _positive(bevel_deg, "bypass_graft_sample: bevel_deg")
    if b > 90.0:
        raise OptionsError(f"bypass_graft_sample: bevel_deg must be in (0, 90], got {bevel_deg}")
    r = _positive(radius, "bypass_graft_sample: radius")
    hood = float(hood)
    gap = float(gap)
    if not (math.isfinite(hood) and hood >= 0.0) or not (math.isfinite(gap) and gap >= 0.0):
        raise OptionsError(
            f"bypass_graft_sample: hood and gap must be finite and >= 0, got hood={hood}, gap={gap}"
        )
    res = _positive(resolution, "bypass_graft_sample: resolution")
    sb, cb = math.sin(math.radians(b)), math.cos(math.radians(b))
    axes = (r / sb + hood, r + hood)  # (along the vessel, around it)
    n_hole = _count(_BYPASS_N_HOLE, res, 12)
    aorta = aortic_wall(15.0, 30.0, 80.0, axes, n_hole, target_edge=1.2 / res, name="aorta")
    aorta = Mesh(aorta.V + [0.0, 0.0, 8.0], aorta.F, name="aorta")
    coronary = aortic_wall(
        _CORONARY_RADIUS,
        30.0,
        360.0,
        axes,
        n_hole,
        target_edge=0.6 / res,
        full_turn=True,
        name="coronary artery",
    )
    # the opening faces -x (towards the aorta): turn the artery half a turn about z
    coronary = Mesh(
        coronary.V @ _rotation("z", 180.0).T + [30.0, 0.0, -10.0],
        coronary.F,
        name="coronary artery",
    )
    a_centre, a_normal = np.array([15.0, 0.0, 8.0]), np.array([1.0, 0.0, 0.0])
    c_centre = np.array([30.0 - _CORONARY_RADIUS, 0.0, -10.0])
    c_normal = np.array([-1.0, 0.0, 0.0])
    down = np.array([sb, 0.0, -cb])  # leaves the aorta and enters the coronary at the bevel
    start, end = a_centre + gap * a_normal, c_centre + gap * c_normal
    reach = np.linalg.norm(end - start) / 3.0
    ctrl = np.array([start, start + reach * down, end - reach * down, end])
    n_around = _count(_BYPASS_N_AROUND, res, 8)
    graft = cut_tube(
        _bezier(ctrl, 256),
        r,
        n_around,
        _count(_BYPASS_N_ALONG, res, 6),
        ((start, a_normal), (end, c_normal)),
        name="graft",
    )
    hole_aorta = next(lp for lp in boundary_loops(aorta.F) if 0 in lp)
    hole_coronary = next(lp for lp in boundary_loops(coronary.F) if 0 in lp)
    return MultiSeamSample(
        name="bypass_graft",
        hosts=[aorta, coronary],
        guest=graft,
        seams=[
            (0, hole_aorta, Curve(loop=_loop_through(graft.F, 0))),
            (1, hole_coronary, Curve(loop=_loop_through(graft.F, graft.n_vertices - n_around))),
        ],
        description=(
            f"Coronary bypass, end-to-side at both ends: a graft (radius {r:g} mm) bevelled at "
            f"{b:g} degrees at both ends, sewn to elliptic openings {hood:g} mm larger than its "
            "ends in the aortic wall (radius 15 mm) and in a coronary artery (radius "
            f"{_CORONARY_RADIUS:g} mm), both in one solve."
        ),
    )


def stiff_patch_sample(
    *, stiff: float = 10.0, resolution: float = 1.0, length: str = "shorter"
) -> tuple[Sample, np.ndarray]:
    """The partial-patch sample with one half of the patch ``stiff`` times stiffer.

    Parameters
    ----------
    stiff : float
        Stiffness of the stiff half relative to the soft half (1).
    resolution : float
    length : {"shorter", "equal", "longer"}

    Returns
    -------
    sample : Sample
    stiffness : ndarray, shape (m,)
        Per guest face: ``stiff`` where the face centre lies on the patch's
        +y side of its long axis (as placed), 1 elsewhere.
    """
    s = paper_sample("partial_patch", length, resolution=resolution)
    V, F = s.guest.V, s.guest.F
    centre = V.mean(axis=0)
    # the patch's short axis as placed: the in-plane direction of least extent
    _, _, Vt = np.linalg.svd(V - centre, full_matrices=False)
    side = (V[F].mean(axis=1) - centre) @ Vt[1]
    return s, np.where(side > 0.0, float(stiff), 1.0)
