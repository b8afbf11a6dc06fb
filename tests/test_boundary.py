"""Tests of boundary loops and curve selection (igljoin.boundary)."""

from __future__ import annotations

import numpy as np
import pytest

from igljoin.boundary import (
    SNAP_DISTANCE,
    Curve,
    SelectedCurve,
    arc_length_parameters,
    boundary_loops,
    polyline_length,
    select_curve,
)
from igljoin.errors import CurveError
from igljoin.mesh import Mesh
from igljoin.phantoms import artery_tube, flat_patch

# ----------------------------------------------------------------------------
# hand-made meshes
# ----------------------------------------------------------------------------


def grid(nx: int, ny: int, hole=(), xmap=None) -> Mesh:
    """Unit-spaced grid in z = 0 with normal +z; vertex ``y * (nx + 1) + x`` is at (x, y).

    ``hole`` lists the cells (x, y) left out; ``xmap`` remaps the x coordinates.
    """
    xs = np.arange(nx + 1, dtype=float) if xmap is None else xmap(np.arange(nx + 1, dtype=float))
    V = np.array([[xs[x], y, 0.0] for y in range(ny + 1) for x in range(nx + 1)])
    F = []
    for y in range(ny):
        for x in range(nx):
            if (x, y) in hole:
                continue
            a = y * (nx + 1) + x
            F += [[a, a + 1, a + nx + 2], [a, a + nx + 2, a + nx + 1]]
    return Mesh(V, np.array(F), name="grid")


def holed() -> Mesh:
    """4 x 4 grid with the central 2 x 2 cells removed: outer loop 16 vertices, hole 8.

    Vertex 12 at (2, 2) lies inside the hole and belongs to no face (on no boundary).
    """
    return grid(4, 4, hole={(1, 1), (2, 1), (1, 2), (2, 2)})


# outer loop counter-clockwise, hole clockwise (both face-induced for normal +z)
OUTER = [0, 1, 2, 3, 4, 9, 14, 19, 24, 23, 22, 21, 20, 15, 10, 5]
INNER = [6, 11, 16, 17, 18, 13, 8, 7]


def tetrahedron() -> Mesh:
    V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    return Mesh(V, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], name="tet")


def relabel(mesh: Mesh, perm: np.ndarray) -> Mesh:
    """The same mesh with vertex ``i`` renamed ``perm[i]``."""
    V = np.empty_like(mesh.V)
    V[perm] = mesh.V
    return Mesh(V, perm[mesh.F], name=mesh.name)


def canonical(loop) -> list[int]:
    """A cyclic sequence rotated to start at its smallest entry."""
    loop = np.asarray(loop)
    return np.roll(loop, -int(np.argmin(loop))).tolist()


def directed_edges(F: np.ndarray) -> set[tuple[int, int]]:
    return {(int(F[f, e]), int(F[f, (e + 1) % 3])) for f in range(len(F)) for e in range(3)}


def assert_face_induced(F: np.ndarray, loop: np.ndarray) -> None:
    """Each consecutive pair (a, b) of the closed loop is a directed face edge a -> b."""
    edges = directed_edges(F)
    for a, b in zip(loop, np.roll(loop, -1)):
        assert (int(a), int(b)) in edges, f"loop step {a} -> {b} is not a face edge"
        assert (int(b), int(a)) not in edges, f"loop step {a} -> {b} is an interior edge"


# ----------------------------------------------------------------------------
# boundary_loops
# ----------------------------------------------------------------------------


def test_boundary_loops_of_grid_with_hole():
    m = holed()
    loops = boundary_loops(m.F)
    assert len(loops) == 2
    assert all(lp.dtype == np.int64 for lp in loops)
    assert canonical(loops[0]) == OUTER
    assert canonical(loops[1]) == INNER
    for lp in loops:
        assert_face_induced(m.F, lp)


def test_boundary_loops_longest_first_whatever_the_labels():
    # rename the hole's vertices 0..7 so that libigl meets the short loop first
    m = holed()
    others = [v for v in range(m.n_vertices) if v not in INNER]
    perm = np.empty(m.n_vertices, dtype=np.int64)
    perm[INNER + others] = np.arange(m.n_vertices)
    r = relabel(m, perm)
    loops = boundary_loops(r.F)
    assert [len(lp) for lp in loops] == [16, 8]
    assert canonical(loops[0]) == canonical(perm[OUTER])
    assert canonical(loops[1]) == canonical(perm[INNER])
    for lp in loops:
        assert_face_induced(r.F, lp)


@pytest.mark.parametrize(
    "mesh",
    [artery_tube(n_around=12, n_along=4), flat_patch(n_boundary=24, n_interior_target=20)],
    ids=["tube", "patch"],
)
def test_boundary_loops_of_phantoms_are_face_induced(mesh):
    loops = boundary_loops(mesh.F)
    assert len(loops) == (2 if mesh.name == "artery" else 1)
    for lp in loops:
        assert_face_induced(mesh.F, lp)


def test_closed_mesh_has_no_boundary_loop():
    assert boundary_loops(tetrahedron().F) == []


# ----------------------------------------------------------------------------
# polyline_length and arc_length_parameters (paper Eq. 1)
# ----------------------------------------------------------------------------

SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def test_polyline_length():
    assert polyline_length(SQUARE, closed=True) == 4.0
    assert polyline_length(SQUARE, closed=False) == 3.0


def test_arc_length_parameters_closed_square():
    t, length = arc_length_parameters(SQUARE, closed=True)
    # quarters of a length-4 loop are exact binary fractions
    np.testing.assert_array_equal(t, [0.0, 0.25, 0.5, 0.75])
    assert length == 4.0


def test_arc_length_parameters_open_polyline():
    P = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]])
    t, length = arc_length_parameters(P, closed=False)
    assert length == 3.0
    assert t[0] == 0.0 and t[-1] == 1.0
    # 1 / 3 is rounded once by the division
    np.testing.assert_allclose(t[1], 1.0 / 3.0, rtol=0, atol=1e-16)


def test_arc_length_parameters_increase():
    rng = np.random.default_rng(7)
    P = rng.normal(size=(50, 3))
    for closed in (True, False):
        t, length = arc_length_parameters(P, closed)
        assert t[0] == 0.0
        assert np.all(np.diff(t) > 0)
        # two summation orders of 50 positive lengths differ by at most ~50 ulps (~1e-14)
        assert length == pytest.approx(polyline_length(P, closed), rel=1e-13)
        if closed:
            assert t[-1] < 1.0


def test_arc_length_parameters_open_end_is_exactly_one():
    bad = []
    for seed in range(20):
        P = np.random.default_rng(seed).normal(size=(122, 3))
        t, _ = arc_length_parameters(P, closed=False)
        if t[-1] != 1.0:
            bad.append(seed)
    assert bad == []


# ----------------------------------------------------------------------------
# SelectedCurve
# ----------------------------------------------------------------------------


def test_reversed_closed_curve_keeps_start():
    c = SelectedCurve(np.array([4, 5, 6, 7]), closed=True, loop=0, forward=True)
    r = c.reversed()
    assert r.indices.tolist() == [4, 7, 6, 5]
    assert (r.closed, r.loop, r.forward) == (True, 0, False)
    assert r.reversed().indices.tolist() == [4, 5, 6, 7]
    assert r.reversed().forward is True


def test_reversed_open_curve_swaps_ends():
    c = SelectedCurve(np.array([4, 5, 6, 7]), closed=False, loop=1, forward=False)
    r = c.reversed()
    assert r.indices.tolist() == [7, 6, 5, 4]
    assert (r.closed, r.loop, r.forward) == (False, 1, True)


def test_rolled():
    c = SelectedCurve(np.array([4, 5, 6, 7]), closed=True, loop=0, forward=True)
    assert c.rolled(1).indices.tolist() == [5, 6, 7, 4]
    assert c.rolled(-1).indices.tolist() == [7, 4, 5, 6]


# ----------------------------------------------------------------------------
# select_curve: ordered indices
# ----------------------------------------------------------------------------


def test_indices_whole_loop_is_closed():
    c = select_curve(holed(), INNER)
    assert c.indices.tolist() == INNER
    assert (c.closed, c.loop, c.forward) == (True, 1, True)
    assert c.indices.dtype == np.int64


def test_indices_whole_loop_started_anywhere():
    idx = np.roll(OUTER, 5)
    c = select_curve(holed(), idx)
    assert c.indices.tolist() == idx.tolist()
    assert (c.closed, c.loop, c.forward) == (True, 0, True)


def test_indices_whole_loop_reversed():
    idx = INNER[::-1]
    c = select_curve(holed(), idx)
    assert c.indices.tolist() == idx
    assert (c.closed, c.forward) == (True, False)


def test_indices_contiguous_part_is_open():
    c = select_curve(holed(), [2, 3, 4, 9])
    assert c.indices.tolist() == [2, 3, 4, 9]
    assert (c.closed, c.loop, c.forward) == (False, 0, True)


def test_indices_part_wrapping_the_loop_start():
    c = select_curve(holed(), [10, 5, 0, 1])
    assert (c.closed, c.forward) == (False, True)


def test_indices_reversed_part():
    c = select_curve(holed(), [14, 9, 4, 3])
    assert c.indices.tolist() == [14, 9, 4, 3]
    assert (c.closed, c.forward) == (False, False)


def test_indices_whole_loop_forced_open():
    c = select_curve(holed(), {"indices": OUTER, "closed": False})
    assert c.indices.tolist() == OUTER
    assert (c.closed, c.forward) == (False, True)


def test_selection_does_not_alias_the_callers_indices():
    idx = np.array(INNER)
    c = select_curve(holed(), idx)
    idx[0] = 0
    assert c.indices[0] == INNER[0]


# ----------------------------------------------------------------------------
# select_curve: start and end, start only, nothing, loop
# ----------------------------------------------------------------------------


def test_start_end_takes_shorter_side():
    c = select_curve(holed(), {"start": 0, "end": 3})
    assert c.indices.tolist() == [0, 1, 2, 3]
    assert (c.closed, c.loop, c.forward) == (False, 0, True)
    c = select_curve(holed(), {"start": 3, "end": 0})
    assert c.indices.tolist() == [3, 2, 1, 0]
    assert (c.closed, c.forward) == (False, False)


def test_start_end_shorter_by_length_not_by_vertex_count():
    # x -> x^2 stretches the right of the grid: from (4, 0) to (4, 4) the path over the
    # right edge has 6 edges of total length 28, the path over the left edge 8 edges, 12.
    m = grid(4, 4, hole={(1, 1), (2, 1), (1, 2), (2, 2)}, xmap=lambda x: x**2)
    c = select_curve(m, {"start": 2, "end": 22})
    assert c.indices.tolist() == [2, 1, 0, 5, 10, 15, 20, 21, 22]
    assert c.forward is False
    V = m.V
    assert polyline_length(V[c.indices], False) == 12.0


def test_via_picks_the_other_side():
    c = select_curve(holed(), {"start": 0, "end": 3, "via": 5})
    assert c.indices.tolist() == [0, 5, 10, 15, 20, 21, 22, 23, 24, 19, 14, 9, 4, 3]
    assert (c.closed, c.forward) == (False, False)
    c = select_curve(holed(), {"start": 0, "end": 3, "via": 2})
    assert c.indices.tolist() == [0, 1, 2, 3]
    assert c.forward is True


def test_start_only_gives_closed_curve_from_start():
    c = select_curve(holed(), {"start": 19})
    assert c.indices.tolist() == np.roll(OUTER, -OUTER.index(19)).tolist()
    assert (c.closed, c.loop, c.forward) == (True, 0, True)
    c = select_curve(holed(), Curve(start=17))
    assert c.indices.tolist() == np.roll(INNER, -INNER.index(17)).tolist()
    assert (c.closed, c.loop, c.forward) == (True, 1, True)


def test_nothing_with_one_loop():
    m = grid(2, 2)
    c = select_curve(m, None)
    assert canonical(c.indices) == [0, 1, 2, 5, 8, 7, 6, 3]
    assert (c.closed, c.loop, c.forward) == (True, 0, True)
    assert_face_induced(m.F, c.indices)


@pytest.mark.parametrize("spec", [1, np.int64(1), {"loop": 1}, Curve(loop=1)])
def test_loop_index(spec):
    c = select_curve(holed(), spec)
    assert canonical(c.indices) == INNER
    assert (c.closed, c.loop, c.forward) == (True, 1, True)


def test_loop_zero_is_the_longest():
    c = select_curve(holed(), 0)
    assert canonical(c.indices) == OUTER


def test_dict_spec_with_start_and_loop():
    c = select_curve(holed(), {"start": 8, "loop": 1})
    assert c.indices[0] == 8 and c.loop == 1 and c.closed


# ----------------------------------------------------------------------------
# select_curve: points snap to the nearest boundary vertex
# ----------------------------------------------------------------------------


def test_point_start_snaps_to_nearest_boundary_vertex():
    # (3.1, -0.2, 0.1) is nearest to vertex 3 at (3, 0, 0)
    c = select_curve(holed(), {"start": [3.1, -0.2, 0.1]})
    assert c.indices[0] == 3 and c.closed


def test_point_snaps_to_boundary_not_interior_vertex():
    # in a 2 x 2 grid the interior vertex 4 at (1, 1) is nearest to (1.1, 1.1); the nearest
    # boundary vertices are 5 at (2, 1) and 7 at (1, 2), equidistant
    c = select_curve(grid(2, 2), {"start": [1.1, 1.1, 0.0]})
    assert c.indices[0] in (5, 7)


def test_points_for_start_end_and_via():
    c = select_curve(
        holed(),
        {"start": [0.05, 0.0, 0.0], "end": [3.0, 0.1, 0.0], "via": [-0.1, 1.0, 0.0]},
    )
    assert c.indices[0] == 0 and c.indices[-1] == 3
    assert c.indices[1] == 5


def test_point_snap_distance_limit():
    # all boundary edges of the grid have length 1, so the limit is SNAP_DISTANCE units;
    # vertex 0 at the origin is the nearest boundary vertex to points on the -x axis
    assert SNAP_DISTANCE == 5.0
    c = select_curve(holed(), {"start": [-4.9, 0.0, 0.0]})
    assert c.indices[0] == 0
    with pytest.raises(CurveError, match="farther than 5 mean boundary edges"):
        select_curve(holed(), {"start": [-5.1, 0.0, 0.0]})


# ----------------------------------------------------------------------------
# select_curve: errors
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "pattern"),
    [
        ([0, 1, 2, 12], r"vertices \[12\] are not on a boundary"),
        ([0, 1, 3], "not consecutive along boundary loop 0"),
        ([0, 2, 1], "not consecutive"),
        ([0], "not consecutive"),
        ([0, 1, 2, 1], "repeat a vertex"),
        ([], "non-empty 1-D array"),
        ([[0, 1, 2]], "non-empty 1-D array"),
        ([0.0, 1.0, 2.0], "non-empty 1-D array"),
        ([0, 1, 99], r"range over \[0, 99\] but the mesh has 25 vertices"),
        ([-1, 0, 1], "range over"),
        ([0, 1], "single edge"),
        ({"indices": [0, 1, 2, 3, 4], "closed": True}, "closed=True but the indices cover 5"),
    ],
    ids=[
        "isolated vertex",
        "gap",
        "zigzag",
        "single vertex",
        "repeat",
        "empty",
        "2-d",
        "float",
        "out of range",
        "negative",
        "single edge",
        "closed partial",
    ],
)
def test_bad_indices(spec, pattern):
    with pytest.raises(CurveError, match=pattern):
        select_curve(holed(), spec, name="guest_curve")


@pytest.mark.parametrize(
    "spec",
    [[1, 2, 5], {"start": 5}, {"start": 0, "end": 5}, {"start": 0, "end": 3, "via": 5}],
    ids=["indices", "start", "end", "via"],
)
def test_interior_vertex_is_rejected(spec):
    # vertex 5 at (1, 1) of a 3 x 3 grid is an interior vertex
    with pytest.raises(CurveError, match="5.* not on a boundary"):
        select_curve(grid(3, 3), spec)


def test_indices_spanning_two_loops():
    # 0, 1, 2 are on the outer loop, 7, 8 on the hole
    with pytest.raises(CurveError, match=r"lie on 2 different boundary loops \(\[0, 1\]\)"):
        select_curve(holed(), [0, 1, 2, 7, 8])


def test_error_messages_name_the_argument():
    with pytest.raises(CurveError, match=r"^host_curve: "):
        select_curve(holed(), [0, 1, 3], name="host_curve")


@pytest.mark.parametrize(
    ("spec", "pattern"),
    [
        ({"start": 12}, r"curve\.start: vertex 12 is not on a boundary"),
        ({"start": 0, "end": 12}, r"curve\.end: vertex 12 is not on a boundary"),
        ({"start": 99}, "vertex 99 is out of range; the mesh has 25 vertices"),
        ({"start": 0, "end": 6}, "start vertex 0 is on boundary loop 0 but end vertex 6 is on"),
        ({"start": 0, "end": 0}, "start and end are the same vertex 0"),
        ({"start": 0, "end": 3, "via": 6}, "via vertex 6 is not on the loop"),
        ({"start": 0, "end": 3, "via": 3}, "via vertex 3 must differ from start and end"),
        ({"start": 0, "end": 1}, "single edge"),
        ({"start": 0, "via": 3}, "'via' needs an 'end' vertex"),
        ({"end": 3}, "'end' and 'via' need a 'start' vertex"),
        ({"start": 0, "loop": 1}, "start vertex 0 is on loop 0, not on loop 1"),
        ({"start": [40.0, 40.0, 0.0]}, "farther than"),
        ({"start": [np.nan, 0.0, 0.0]}, "is not finite"),
        ({"start": True}, "expected a vertex index or a 3D point"),
        ({"start": [0.0, 1.0]}, "expected a vertex index or a 3D point"),
        ({"begin": 0}, r"unknown curve keys \['begin'\]; use indices, start, end"),
        (2, "loop 2 does not exist; grid has 2 boundary loops"),
        ({"loop": -1}, "loop -1 does not exist"),
        (None, r"has 2 boundary loops \(sizes \[16, 8\]\); say which"),
    ],
    ids=[
        "start isolated",
        "end isolated",
        "start out of range",
        "different loops",
        "start is end",
        "via off loop",
        "via is end",
        "single edge",
        "via without end",
        "end without start",
        "start off loop",
        "far point",
        "nan point",
        "bool",
        "2-d point",
        "unknown key",
        "loop out of range",
        "negative loop",
        "several loops",
    ],
)
def test_bad_selection(spec, pattern):
    with pytest.raises(CurveError, match=pattern):
        select_curve(holed(), spec)


def test_mesh_without_boundary():
    with pytest.raises(CurveError, match="tet has no boundary loop .*cut an opening"):
        select_curve(tetrahedron(), None, name="host_curve")
