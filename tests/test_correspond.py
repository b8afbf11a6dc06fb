"""Tests of curve pairing and point correspondence (igljoin.correspond, paper §4.1)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from igljoin.boundary import SelectedCurve, arc_length_parameters, boundary_loops, select_curve
from igljoin.correspond import Correspondence, correspond, curve_points_at, pair_curves
from igljoin.errors import CurveError
from igljoin.mesh import Mesh
from igljoin.phantoms import paper_sample

# ----------------------------------------------------------------------------
# hand-made meshes
# ----------------------------------------------------------------------------


def wobbly_ring(n: int, phase: float = 0.0, scale: float = 1.0) -> np.ndarray:
    """``n`` points (counter-clockwise about +z) on a closed planar curve with no symmetry."""
    th = 2.0 * np.pi * (np.arange(n) + phase) / n
    r = scale * (1.0 + 0.3 * np.cos(th) + 0.1 * np.sin(2 * th) + 0.05 * np.cos(3 * th))
    return np.column_stack([r * np.cos(th), r * np.sin(th), np.zeros(n)])


def disc(P: np.ndarray) -> Mesh:
    """Fan of triangles from the centroid; boundary vertices ``0..n-1``, normal +z."""
    n = len(P)
    F = [[i, (i + 1) % n, n] for i in range(n)]
    return Mesh(np.vstack([P, P.mean(axis=0)]), F, name="disc")


def annulus(P: np.ndarray) -> Mesh:
    """Ring between ``P`` (the hole, vertices ``0..n-1``) and ``2 P``; normal +z."""
    n = len(P)
    F = []
    for i in range(n):
        j = (i + 1) % n
        F += [[i, n + j, j], [i, n + i, n + j]]
    return Mesh(np.vstack([P, 2.0 * P]), F, name="annulus")


def hole_curve(host: Mesh) -> SelectedCurve:
    """The hole of an :func:`annulus` (the loop through vertex 0), face-induced order."""
    loop = next(lp for lp in boundary_loops(host.F) if 0 in lp)
    return select_curve(host, loop)


def strip(xs: np.ndarray, y0: float, y1: float) -> Mesh:
    """Quad strip between rows ``y = y0`` (vertices ``0..n-1``) and ``y = y1`` (``n..2n-1``)."""
    n = len(xs)
    V = np.vstack(
        [
            np.column_stack([xs, np.full(n, y0), np.zeros(n)]),
            np.column_stack([xs, np.full(n, y1), np.zeros(n)]),
        ]
    )
    F = []
    for i in range(n - 1):
        F += [[i, i + 1, n + i + 1], [i, n + i + 1, n + i]]
    F = np.array(F)
    if y1 > y0:
        return Mesh(V, F, name="strip")
    return Mesh(V, F[:, ::-1], name="strip")  # keep normal +z


def square_hole_host(inner: np.ndarray) -> Mesh:
    """Annulus whose hole is the 2D polygon ``inner`` (counter-clockwise), normal +z."""
    c = inner.mean(axis=0)
    P = np.column_stack([inner, np.zeros(len(inner))])
    outer = np.column_stack([(inner - c) * 3.0 + c, np.zeros(len(inner))])
    n = len(inner)
    F = []
    for i in range(n):
        j = (i + 1) % n
        F += [[i, n + j, j], [i, n + i, n + j]]
    return Mesh(np.vstack([P, outer]), F, name="square host")


# ----------------------------------------------------------------------------
# independent geometry helpers
# ----------------------------------------------------------------------------


def double_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def unit_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def point_at_arc_length(P: np.ndarray, closed: bool, t: float) -> np.ndarray:
    """The point at normalised arc length ``t`` of a polyline, walking its segments."""
    Q = np.vstack([P, P[:1]]) if closed else P
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    s = t * seg.sum()
    for j, length in enumerate(seg):
        if s <= length or j == len(seg) - 1:
            f = s / length
            return Q[j] * (1.0 - f) + Q[j + 1] * f
        s -= length
    raise AssertionError("unreachable")


# ----------------------------------------------------------------------------
# cases: (guest V, guest F, paired guest curve, host V, paired host curve, snap tolerance)
# ----------------------------------------------------------------------------


def _closed_case(n_host, n_guest, tol):
    host = annulus(wobbly_ring(n_host))
    guest = disc(wobbly_ring(n_guest, phase=0.3, scale=1.1))
    H, G, _ = pair_curves(
        host.V, hole_curve(host), guest.V, select_curve(guest, None), guest_start_given=False
    )
    return guest.V, guest.F, G, host.V, H, tol


def _open_case(seed, tol, reverse=False):
    rng = np.random.default_rng(seed)
    n_h, n_g = rng.integers(3, 30, size=2)
    xh = np.sort(np.r_[0.0, rng.uniform(0.0, 1.0, n_h - 2), 1.0])
    xg = np.sort(np.r_[0.0, rng.uniform(0.0, 1.0, n_g - 2), 1.0]) * rng.uniform(0.7, 1.3)
    host = strip(xh, 0.0, -1.0)
    guest = strip(xg, 1.0, 0.2)
    hc = select_curve(host, {"start": 0, "end": n_h - 1})  # the row y = 0
    gc = select_curve(guest, {"start": n_g, "end": 2 * n_g - 1})  # the row y = 0.2
    assert gc.forward != hc.forward  # opposite face orders, as for a weld
    if reverse:  # both run from x = 1 to x = 0 instead
        hc, gc = hc.reversed(), gc.reversed()
    H, G, _ = pair_curves(host.V, hc, guest.V, gc, guest_start_given=True)
    return guest.V, guest.F, G, host.V, H, tol


def _phantom_case(scenario, resolution, guest_resolution):
    s = paper_sample(scenario, "equal", resolution=resolution, guest_resolution=guest_resolution)
    hc = select_curve(s.host, s.host_curve, name="host_curve")
    gc = select_curve(s.guest, s.guest_curve, name="guest_curve")
    H, G, _ = pair_curves(s.host.V, hc, s.guest.V, gc, guest_start_given=not s.closed)
    return s.guest.V, s.guest.F, G, s.host.V, H, 0.1


CASES = {
    "closed 12 host / 7 guest": lambda: _closed_case(12, 7, 0.1),
    "closed 12 host / 30 guest": lambda: _closed_case(12, 30, 0.1),
    "closed 40 host / 8 guest, tol 0": lambda: _closed_case(40, 8, 0.0),
    "closed 13 host / 5 guest, tol 0.49": lambda: _closed_case(13, 5, 0.49),
    "open seed 1": lambda: _open_case(1, 0.1),
    "open seed 2, tol 0.3": lambda: _open_case(2, 0.3),
    "open seed 3, tol 0": lambda: _open_case(3, 0.0),
    "open seed 4, reversed": lambda: _open_case(4, 0.1, reverse=True),
    "partial_patch coarse guest": lambda: _phantom_case("partial_patch", 1.0, 0.2),
    "partial_patch fine guest": lambda: _phantom_case("partial_patch", 0.3, 3.0),
    "end_to_end": lambda: _phantom_case("end_to_end", 0.3, 1.0),
    "open_strip": lambda: _phantom_case("open_strip", 0.5, 1.0),
}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    Vg, Fg, G, Vh, H, tol = CASES[request.param]()
    c = correspond(Vg, Fg, G, Vh, H, snap_fraction=tol)
    return Vg, Fg, G, Vh, H, c


# ----------------------------------------------------------------------------
# pair_curves
# ----------------------------------------------------------------------------


def test_pair_rejects_open_with_closed():
    host = annulus(wobbly_ring(10))
    guest = strip(np.linspace(0.0, 1.0, 5), 1.0, 0.0)
    hc = hole_curve(host)
    gc = select_curve(guest, {"start": 5, "end": 9})
    with pytest.raises(CurveError, match="host_curve is closed but guest_curve is open"):
        pair_curves(host.V, hc, guest.V, gc, guest_start_given=True)
    with pytest.raises(CurveError, match="host_curve is open but guest_curve is closed"):
        pair_curves(guest.V, gc, host.V, hc, guest_start_given=True)


@pytest.mark.parametrize("which", ["host_curve", "guest_curve"])
def test_pair_rejects_zero_length_curve(which):
    good = wobbly_ring(6)
    flat = np.zeros((6, 3))  # all curve vertices coincide
    curve = SelectedCurve(np.arange(6), closed=True, loop=0, forward=True)
    Vh, Vg = (flat, good) if which == "host_curve" else (good, flat)
    with pytest.raises(CurveError, match=f"{which} has length zero"):
        pair_curves(Vh, curve, Vg, curve.reversed(), guest_start_given=False)


@pytest.mark.parametrize("host_forward", [True, False])
@pytest.mark.parametrize("guest_forward", [True, False])
@pytest.mark.parametrize("start_given", [True, False])
def test_pair_closed_guest_runs_against_host(host_forward, guest_forward, start_given):
    P = wobbly_ring(12)
    host, guest = annulus(P), disc(P)
    hc = hole_curve(host)
    gc = select_curve(guest, None)
    if not host_forward:
        hc = hc.reversed()
    if not guest_forward:
        gc = gc.reversed()
    H, G, info = pair_curves(host.V, hc, guest.V, gc, guest_start_given=start_given)
    assert H == hc
    assert G.forward != H.forward
    assert G.closed and sorted(G.indices) == list(range(12))
    # G is the guest loop in the order opposite to the host's: a cyclic shift of one of the
    # two traversals, chosen by the host's direction
    order = np.arange(12) if not host_forward else np.roll(np.arange(12)[::-1], 1)
    k = int(np.flatnonzero(order == G.indices[0])[0])
    assert G.indices.tolist() == np.roll(order, -k).tolist()
    if not start_given:  # identical loops: the fit finds the exact match
        np.testing.assert_array_equal(guest.V[G.indices], host.V[H.indices])
    assert set(info) == {"fit_residual", "reverse_fit_residual"}


@pytest.mark.parametrize(
    ("n", "shift"),
    [(12, 0), (12, 1), (12, 5), (12, 11), (300, 1), (300, 37)],
)
def test_pair_recovers_a_cyclic_shift(n, shift):
    # 300 vertices are finer than the 128-sample coarse search: the exact refinement counts
    P = wobbly_ring(n)
    host = annulus(P)
    guest = disc(np.roll(P, shift, axis=0))  # guest vertex i sits on host vertex i - shift
    H, G, info = pair_curves(
        host.V, hole_curve(host), guest.V, select_curve(guest, None), guest_start_given=False
    )
    # the loops are identical, so every guest curve vertex lands on its host vertex
    np.testing.assert_array_equal(guest.V[G.indices], host.V[H.indices])
    assert G.indices[0] == (H.indices[0] + shift) % n
    # identical shapes fit perfectly: the residual cancels terms of size 128 (the number of
    # unit-RMS samples), leaving rounding of ~1e-13; 1e-9 is a wide margin
    assert abs(info["fit_residual"]) < 1e-9
    # the curve has no symmetry, so running it the other way fits clearly worse (~0.2)
    assert info["reverse_fit_residual"] > 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pair_start_is_invariant_to_rigid_motion_of_guest(seed):
    host = annulus(wobbly_ring(23))
    guest = disc(wobbly_ring(17, phase=0.4, scale=1.2))  # a different sampling and size
    hc, gc = hole_curve(host), select_curve(guest, None)
    _, G0, info0 = pair_curves(host.V, hc, guest.V, gc, guest_start_given=False)
    R = Rotation.random(random_state=seed).as_matrix()
    shift = np.random.default_rng(seed).normal(scale=10.0, size=3)
    moved = guest.V @ R.T + shift
    _, G1, info1 = pair_curves(host.V, hc, moved, gc, guest_start_given=False)
    np.testing.assert_array_equal(G1.indices, G0.indices)
    # the residual depends on shapes only; rounding of sums of size 128 and of 3x3 SVDs
    # stays near 1e-13
    assert info1["fit_residual"] == pytest.approx(info0["fit_residual"], abs=1e-9)


def test_pair_start_matches_the_nearest_host_start():
    # the guest is the host's hole curve resampled at other points; its best start is the
    # guest vertex nearest host vertex 0 in arc length
    host = annulus(wobbly_ring(30))
    guest = disc(wobbly_ring(30, phase=0.2))
    H, G, _ = pair_curves(
        host.V, hole_curve(host), guest.V, select_curve(guest, None), guest_start_given=False
    )
    d = np.linalg.norm(guest.V[:30] - host.V[H.indices[0]], axis=1)
    assert G.indices[0] == int(np.argmin(d))


def test_pair_keeps_a_given_guest_start():
    P = wobbly_ring(12)
    host, guest = annulus(P), disc(P)
    gc = select_curve(guest, {"start": 4})
    H, G, _ = pair_curves(host.V, hole_curve(host), guest.V, gc, guest_start_given=True)
    assert G.indices.tolist() == gc.reversed().indices.tolist()
    assert G.indices[0] == 4


def test_pair_leaves_open_curves_alone():
    host = strip(np.linspace(0.0, 1.0, 6), 0.0, -1.0)
    guest = strip(np.linspace(0.0, 1.0, 4), 1.0, 0.0)
    hc = select_curve(host, {"start": 0, "end": 5})
    gc = select_curve(guest, {"start": 4, "end": 7})
    H, G, info = pair_curves(host.V, hc, guest.V, gc, guest_start_given=True)
    assert H == hc and G == gc and info == {}


# ----------------------------------------------------------------------------
# curve_points_at
# ----------------------------------------------------------------------------

SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def test_curve_points_at_closed_square():
    t, _ = arc_length_parameters(SQUARE, closed=True)
    pts, seg, frac = curve_points_at(SQUARE, t, np.array([0.0, 0.125, 0.25, 0.9]), True)
    # all parameters and results are exact binary fractions except 0.9 (0.6 along edge 3)
    np.testing.assert_allclose(
        pts, [[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [0, 0.4, 0]], rtol=0, atol=1e-15
    )
    assert seg.tolist() == [0, 0, 1, 3]
    np.testing.assert_allclose(frac, [0.0, 0.5, 0.0, 0.6], rtol=0, atol=1e-15)


def test_curve_points_at_open_end():
    P = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]])
    t, _ = arc_length_parameters(P, closed=False)
    pts, seg, frac = curve_points_at(P, t, np.array([0.0, 0.5, 1.0]), False)
    # 0.5 of length 3 is 0.5 up the second segment; 1/3 rounding gives ~1e-16 errors
    np.testing.assert_allclose(pts, [[0, 0, 0], [1, 0.5, 0], [1, 2, 0]], rtol=0, atol=1e-14)
    assert seg.tolist() == [0, 1, 1]
    np.testing.assert_allclose(frac, [0.0, 0.25, 1.0], rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------
# correspond: properties on every case
# ----------------------------------------------------------------------------


def test_result_type(case):
    *_, c = case
    assert isinstance(c, Correspondence)
    assert c.F.dtype == np.int64 and c.seam.dtype == np.int64 and c.host_hit.dtype == np.int64


def test_host_vertices_are_hit_exactly(case):
    Vg, Fg, G, Vh, H, c = case
    P_v = Vh[H.indices]
    assert c.host_hit.shape == (len(H.indices),)
    assert np.unique(c.host_hit).size == len(H.indices)
    # exact equality: the target of a hit is the host vertex itself, not an interpolation
    np.testing.assert_array_equal(c.targets[c.host_hit], P_v)
    np.testing.assert_array_equal(c.host_edge_t[c.host_hit][:-1], 0.0)
    # the seam meets the host vertices in host curve order
    assert c.host_hit[0] == 0
    assert np.all(np.diff(c.host_hit) > 0)


def test_unsnapped_guest_vertices_follow_arc_length(case):
    Vg, Fg, G, Vh, H, c = case
    t_u, _ = arc_length_parameters(Vg[G.indices], G.closed)
    pos_in_curve = {int(v): i for i, v in enumerate(G.indices)}
    free = np.ones(len(c.seam), dtype=bool)
    free[c.host_hit] = False
    free &= c.seam < c.n_original
    for p in np.flatnonzero(free):
        i = pos_in_curve[int(c.seam[p])]
        assert c.seam_t[p] == t_u[i]
        expected = point_at_arc_length(Vh[H.indices], H.closed, t_u[i])
        # Eq. 1 evaluated two ways on coordinates up to ~20 mm: a few ulps (~1e-14) apart
        np.testing.assert_allclose(c.targets[p], expected, rtol=0, atol=1e-12)


def test_targets_agree_with_host_edge_and_parameter(case):
    Vg, Fg, G, Vh, H, c = case
    P_v = Vh[H.indices]
    j = c.host_edge
    assert np.all((c.host_edge_t >= 0.0) & (c.host_edge_t <= 1.0))
    if H.closed:
        assert np.all(c.host_edge_t < 1.0)
    nxt = (j + 1) % len(P_v)
    q = P_v[j] * (1.0 - c.host_edge_t)[:, None] + P_v[nxt] * c.host_edge_t[:, None]
    # one linear interpolation of coordinates up to ~20 mm: a few ulps (~1e-14)
    np.testing.assert_allclose(q, c.targets, rtol=0, atol=1e-12)


def test_inserted_vertices_are_appended_on_guest_boundary_edges(case):
    Vg, Fg, G, Vh, H, c = case
    n0 = c.n_original
    k = len(c.V) - n0
    assert n0 == len(Vg)
    np.testing.assert_array_equal(c.V[:n0], Vg)  # original vertices untouched, first
    assert c.inserted_from.shape == (k, 2) and c.inserted_t.shape == (k,)
    assert np.all((c.inserted_t > 0.0) & (c.inserted_t < 1.0))
    curve_edges = {(int(a), int(b)) for a, b in zip(G.indices[:-1], G.indices[1:])}
    if G.closed:
        curve_edges.add((int(G.indices[-1]), int(G.indices[0])))
    for i, (a, b) in enumerate(c.inserted_from):
        assert (int(a), int(b)) in curve_edges
        x = c.V[n0 + i]
        ab = Vg[b] - Vg[a]
        s = np.dot(x - Vg[a], ab) / np.dot(ab, ab)
        # on the segment: coordinates up to ~20 mm and parameters in (0, 1) agree to a few
        # ulps (~1e-14); 1e-12 leaves room for the projection's own rounding
        np.testing.assert_allclose(x, Vg[a] + s * ab, rtol=0, atol=1e-12)
        assert s == pytest.approx(c.inserted_t[i], abs=1e-12)
    # the seam is the guest curve plus every inserted vertex, each once
    expected = np.sort(np.concatenate([G.indices, n0 + np.arange(k)]))
    np.testing.assert_array_equal(np.sort(c.seam), expected)


def test_seam_is_ordered_by_parameter(case):
    *_, G, Vh, H, c = case
    assert c.seam.shape == c.seam_t.shape == c.host_edge.shape == (len(c.targets),)
    assert c.seam_t[0] == 0.0
    assert np.all(np.diff(c.seam_t) > 0.0)
    assert np.all(c.seam_t <= 1.0)
    # original guest vertices keep their curve order inside the seam
    orig = c.seam[c.seam < c.n_original]
    np.testing.assert_array_equal(orig, G.indices)


def test_split_preserves_area_and_orientation(case):
    Vg, Fg, G, Vh, H, c = case
    A0 = double_areas(Vg, Fg)
    A1 = double_areas(c.V, c.F)
    assert len(c.F) == len(Fg) + (len(c.V) - c.n_original)  # one face per inserted vertex
    assert c.face_parent.shape == (len(c.F),)
    # per parent face: children tile it exactly; sums of a few areas differ by a few ulps
    # (relative ~1e-15), so 1e-12 only tolerates rounding, never a missing piece
    per_parent = np.bincount(c.face_parent, A1, minlength=len(Fg))
    np.testing.assert_allclose(per_parent, A0, rtol=1e-12, atol=0)
    assert A1.sum() == pytest.approx(A0.sum(), rel=1e-12)
    assert A1.min() > 0.0
    # a child is a planar piece of its parent, so unit normals agree up to rounding; the
    # thinnest children (splits clipped 1e-9 from a vertex) lose ~eps/1e-9 ~ 1e-7 of angle,
    # i.e. ~1e-14 of the dot product, well inside 1e-9
    dots = np.sum(unit_normals(c.V, c.F) * unit_normals(Vg, Fg)[c.face_parent], axis=1)
    assert dots.min() > 1.0 - 1e-9


def test_refined_guest_is_edge_manifold_and_oriented(case):
    Vg, Fg, G, Vh, H, c = case
    E = np.concatenate([c.F[:, [0, 1]], c.F[:, [1, 2]], c.F[:, [2, 0]]])
    assert len(np.unique(E, axis=0)) == len(E)  # no directed edge twice: consistent
    _, count = np.unique(np.sort(E, axis=1), axis=0, return_counts=True)
    assert count.max() <= 2
    assert len(np.unique(np.sort(c.F, axis=1), axis=0)) == len(c.F)  # no duplicate face
    # the seam (closed) or the refined open curve runs along the refined boundary
    loops = boundary_loops(c.F)
    assert len(loops) == len(boundary_loops(Fg))
    on_boundary = np.zeros(len(c.V), dtype=bool)
    on_boundary[np.concatenate(loops)] = True
    assert on_boundary[c.seam].all()
    edges = {tuple(sorted(e)) for e in E.tolist()}
    steps = zip(c.seam, np.roll(c.seam, -1)) if G.closed else zip(c.seam[:-1], c.seam[1:])
    for a, b in steps:
        assert tuple(sorted((int(a), int(b)))) in edges


# ----------------------------------------------------------------------------
# correspond: specific configurations
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_open_curve_maps_start_to_start_and_end_to_end(seed):
    Vg, Fg, G, Vh, H, tol = _open_case(seed, 0.1)
    c = correspond(Vg, Fg, G, Vh, H, snap_fraction=tol)
    assert c.seam[0] == G.indices[0] and c.seam[-1] == G.indices[-1]
    np.testing.assert_array_equal(c.targets[0], Vh[H.indices[0]])
    np.testing.assert_array_equal(c.targets[-1], Vh[H.indices[-1]])
    assert (c.host_hit[0], c.host_hit[-1]) == (0, len(c.seam) - 1)
    assert (c.host_edge[-1], c.host_edge_t[-1]) == (len(H.indices) - 2, 1.0)


def test_snap_fraction_decides_between_snap_and_insert():
    # guest row at x = 0, 0.5, 1 and host row at x = 0, 0.52, 1: host vertex 1 is 0.04 of a
    # guest edge away from guest vertex 1
    host = strip(np.array([0.0, 0.52, 1.0]), 0.0, -1.0)
    guest = strip(np.array([0.0, 0.5, 1.0]), 1.0, 0.0)
    hc = select_curve(host, {"start": 0, "end": 2})
    gc = select_curve(guest, {"start": 3, "end": 5})
    snapped = correspond(guest.V, guest.F, gc, host.V, hc, snap_fraction=0.1)
    assert len(snapped.V) == 6 and snapped.seam.tolist() == [3, 4, 5]
    np.testing.assert_array_equal(snapped.targets, host.V[[0, 1, 2]])
    inserted = correspond(guest.V, guest.F, gc, host.V, hc, snap_fraction=0.03)
    assert inserted.seam.tolist() == [3, 4, 6, 5]
    assert inserted.inserted_from.tolist() == [[4, 5]]
    # 0.52 is 0.04 of the way from 0.5 to 1 (rounding of 0.02 / 0.5)
    assert inserted.inserted_t[0] == pytest.approx(0.04, abs=1e-15)
    np.testing.assert_allclose(inserted.V[6], [0.52, 0.0, 0.0], rtol=0, atol=1e-15)
    # guest vertex 4 (t = 0.5) goes to the host point at t = 0.5, x = 0.5
    np.testing.assert_allclose(inserted.targets[1], [0.5, 0.0, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(inserted.targets[2], host.V[1])


def test_host_vertex_snaps_to_the_nearer_guest_vertex():
    # guest row at x = 0, 1, 2, 3 and host row at x = 0, 1.55, 3: host vertex 1 lands at
    # x = 1.55 on the guest curve, 0.55 of the edge from guest vertex 1 and 0.45 from vertex 2
    host = strip(np.array([0.0, 1.55, 3.0]), 0.0, -1.0)
    guest = strip(np.array([0.0, 1.0, 2.0, 3.0]), 1.0, 0.0)
    hc = select_curve(host, {"start": 0, "end": 2})
    gc = select_curve(guest, {"start": 4, "end": 7})
    c = correspond(guest.V, guest.F, gc, host.V, hc, snap_fraction=0.46)
    assert len(c.V) == 8  # no insertion
    assert c.seam.tolist() == [4, 5, 6, 7]
    assert c.host_hit.tolist() == [0, 2, 3]
    np.testing.assert_array_equal(c.targets[2], host.V[1])
    # guest vertex 5 (t = 1/3) goes to the host point at x = 1 (rounding of 1/3 * 3)
    np.testing.assert_allclose(c.targets[1], [1.0, 0.0, 0.0], rtol=0, atol=1e-15)
    c = correspond(guest.V, guest.F, gc, host.V, hc, snap_fraction=0.44)
    assert c.seam.tolist() == [4, 5, 8, 6, 7]


def test_identical_curves_need_no_insertion():
    P = wobbly_ring(15)
    host, guest = annulus(P), disc(np.roll(P, 4, axis=0))
    H, G, _ = pair_curves(
        host.V, hole_curve(host), guest.V, select_curve(guest, None), guest_start_given=False
    )
    c = correspond(guest.V, guest.F, G, host.V, H)
    assert len(c.V) == guest.n_vertices
    np.testing.assert_array_equal(c.F, guest.F)
    np.testing.assert_array_equal(c.seam, G.indices)
    np.testing.assert_array_equal(c.host_hit, np.arange(15))
    np.testing.assert_array_equal(c.targets, guest.V[G.indices])


def test_coarse_guest_gets_insertions():
    s = paper_sample("partial_patch", "equal", guest_resolution=0.2)
    (g_loop,) = boundary_loops(s.guest.F)
    hc = select_curve(s.host, s.host_curve, name="host_curve")
    gc = select_curve(s.guest, s.guest_curve, name="guest_curve")
    H, G, _ = pair_curves(s.host.V, hc, s.guest.V, gc, guest_start_given=False)
    c = correspond(s.guest.V, s.guest.F, G, s.host.V, H)
    n_u, n_v = len(g_loop), len(H.indices)
    assert n_v >= 4 * n_u  # the guest is about 5 x coarser along the seam
    k = len(c.V) - c.n_original
    # each guest vertex takes at most one host vertex; all others are inserted
    assert k >= n_v - n_u
    assert len(c.seam) == n_u + k
    np.testing.assert_array_equal(c.targets[c.host_hit], s.host.V[H.indices])


def test_corner_triangles_with_two_split_edges():
    # a unit square of two triangles, each with two boundary edges; the host's hole is the
    # same square with its edge midpoints as extra vertices
    guest = Mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    inner = np.array([[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1], [0, 1], [0, 0.5]])
    host = square_hole_host(inner)
    H = hole_curve(host)
    G = select_curve(guest, [0, 3, 2, 1])  # against the guest's face order, from (0, 0)
    np.testing.assert_array_equal(guest.V[G.indices], host.V[H.indices[::2]])
    c = correspond(guest.V, guest.F, G, host.V, H)
    assert len(c.V) == 8 and len(c.F) == 6
    # the four inserted vertices are the edge midpoints (0.5 is exact)
    mids = {tuple(p) for p in c.V[4:].tolist()}
    assert mids == {(0.5, 0.0, 0.0), (1.0, 0.5, 0.0), (0.5, 1.0, 0.0), (0.0, 0.5, 0.0)}
    np.testing.assert_array_equal(c.targets, host.V[H.indices])
    # each parent is cut in three; the children tile it without overlap or gap
    assert np.bincount(c.face_parent).tolist() == [3, 3]
    np.testing.assert_array_equal(np.bincount(c.face_parent, double_areas(c.V, c.F)), [1, 1])
    assert len(np.unique(np.sort(c.F, axis=1), axis=0)) == 6
    np.testing.assert_array_equal(unit_normals(c.V, c.F)[:, 2], 1.0)
    (loop,) = boundary_loops(c.F)
    assert len(loop) == 8 and set(loop) == set(range(8))


def test_single_triangle_with_three_split_edges():
    guest = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    inner = np.array([[0, 0], [0.5, 0], [1, 0], [0.5, 0.5], [0, 1], [0, 0.5]])
    host = square_hole_host(inner)
    H = hole_curve(host)
    G = select_curve(guest, [0, 2, 1])
    np.testing.assert_array_equal(guest.V[G.indices], host.V[H.indices[::2]])
    c = correspond(guest.V, guest.F, G, host.V, H)
    assert len(c.V) == 6 and len(c.F) == 4
    np.testing.assert_array_equal(c.targets, host.V[H.indices])
    np.testing.assert_array_equal(c.face_parent, 0)
    A = double_areas(c.V, c.F)
    # four triangles tiling the unit right triangle (doubled area 1); 0.5 splits are exact
    assert A.sum() == 1.0 and A.min() > 0.0
    np.testing.assert_array_equal(unit_normals(c.V, c.F)[:, 2], 1.0)
    (loop,) = boundary_loops(c.F)
    assert len(loop) == 6
