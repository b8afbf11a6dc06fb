"""Join-quality metrics on cases with known answers (issue: welded output and quality report)."""

from __future__ import annotations

import dataclasses
import json

import igl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import igljoin
from igljoin import metrics, phantoms

from .cuts import cut_piece


def _grid(n: int, size: float = 10.0) -> igljoin.Mesh:
    """A flat n x n vertex square grid in the plane z = 0, quads split along one diagonal."""
    x = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(n * n)])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b, c, d = a + n, a + n + 1, a + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return igljoin.Mesh(V, F, name="flat grid")


def _rigid(V, seed=3):
    R = Rotation.from_rotvec(np.random.default_rng(seed).normal(size=3)).as_matrix()
    return V @ R.T + np.array([3.0, -7.0, 11.0])


# -- deformation maps -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def patch():
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.5).guest


def test_rigid_motion_is_no_deformation(patch):
    V0, F = patch.V, patch.F
    V1 = _rigid(V0)
    E = np.asarray(igl.edges(F), dtype=np.int64)
    size = float(np.linalg.norm(np.ptp(V0, axis=0)))
    # 1e-12: a rigid motion changes lengths and areas only by float64 rounding
    np.testing.assert_allclose(metrics.area_ratio(V0, V1, F), 1.0, atol=1e-12)
    strain = metrics.edge_strain(V0, V1, E)
    assert np.abs(strain).max() <= 1e-12
    assert np.abs(metrics.vertex_strain(E, strain, len(V0))).max() <= 1e-12
    # 1e-12 of the patch size: the Kabsch fit recovers the motion up to rounding
    assert metrics.nonrigid_displacement(V0, V1).max() <= 1e-12 * size


def test_uniform_scaling_has_known_maps(patch):
    V0, F = patch.V, patch.F
    centroid = V0.mean(axis=0)
    V1 = _rigid(centroid + 2.0 * (V0 - centroid))
    E = np.asarray(igl.edges(F), dtype=np.int64)
    # twice as long: area x4, every edge strain +1, every vertex strain +1 (1e-12: rounding)
    np.testing.assert_allclose(metrics.area_ratio(V0, V1, F), 4.0, rtol=1e-12)
    strain = metrics.edge_strain(V0, V1, E)
    np.testing.assert_allclose(strain, 1.0, rtol=1e-12)
    np.testing.assert_allclose(metrics.vertex_strain(E, strain, len(V0)), 1.0, rtol=1e-12)
    # the best rotation+translation of a scaled copy leaves each vertex off by its
    # distance from the centroid (scale 2 - 1); 1e-9: SVD rounding on ~1e3 points
    expected = np.linalg.norm(V0 - centroid, axis=1)
    np.testing.assert_allclose(metrics.nonrigid_displacement(V0, V1), expected, atol=1e-9)


def test_vertex_strain_is_the_mean_of_incident_edges():
    E = np.array([[0, 1], [1, 2], [2, 0], [2, 3]])
    s = np.array([0.3, -0.1, np.nan, 0.5])
    out = metrics.vertex_strain(E, s, 5)
    # vertex 0: only (0,1) finite; 1: (0,1),(1,2); 2: (1,2),(2,3); 3: (2,3); 4: no edge
    # (rtol 1e-15: a mean of at most two numbers, one rounding)
    np.testing.assert_allclose(out[:4], [0.3, 0.1, 0.2, 0.5], rtol=1e-15)
    assert np.isnan(out[4])


def test_folded_pairs_known_answer():
    V0 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    assert len(metrics.folded_pairs(V0, V0, F)) == 0
    # vertex 3 turned about the shared edge by 170 degrees: the faces fold onto each other
    axis = (V0[2] - V0[1]) / np.linalg.norm(V0[2] - V0[1])
    R = Rotation.from_rotvec(np.radians(170.0) * axis).as_matrix()
    V1 = V0.copy()
    V1[3] = V0[1] + (V0[3] - V0[1]) @ R.T
    assert metrics.folded_pairs(V0, V1, F).tolist() == [[0, 1]]
    # 140 degrees is below the default 150-degree threshold
    R = Rotation.from_rotvec(np.radians(140.0) * axis).as_matrix()
    V1[3] = V0[1] + (V0[3] - V0[1]) @ R.T
    assert len(metrics.folded_pairs(V0, V1, F)) == 0
    _, angle = metrics.edge_dihedral_angles(V1, F)
    # the same turn read as a dihedral angle (1e-9 degrees: rotation rounding)
    assert abs(angle[0] - 140.0) <= 1e-9


# -- dihedral angles --------------------------------------------------------------------------


def test_flat_mesh_has_zero_dihedral_angles():
    grid = _grid(8)
    edges, angles = metrics.edge_dihedral_angles(grid.V, grid.F)
    # interior edges of an n x n grid: 3 (n-1)^2 + 2 (n-1) edges in all, minus 4 (n-1) on
    # the boundary
    assert len(edges) == 3 * 49 + 2 * 7 - 4 * 7
    # 1e-5 degrees: arccos near 1 turns a cosine rounded by k ulps (1.1e-16 each) into
    # sqrt(2 k 1.1e-16) rad, i.e. about 1e-6 sqrt(k) degrees
    assert angles.max() <= 1e-5
    curve = igljoin.boundary_loops(grid.F)[0]
    assert metrics.host_dihedral_angles(grid.V, grid.F, curve).max() <= 1e-5


def test_hexagonal_prism_has_sixty_degree_edges():
    n_along = 4
    tube = phantoms.artery_tube(2.0, 5.0, n_around=6, n_along=n_along)
    edges, angles = metrics.edge_dihedral_angles(tube.V, tube.F)
    turn = np.abs(angles - 60.0) <= 1e-9  # 1e-9 degrees: exact hexagon, float rounding only
    flat = angles <= 1e-5  # diagonals and ring edges are flat (arccos rounding, see above)
    assert (turn | flat).all()
    # the axial side edges: 6 per band of quads
    assert turn.sum() == 6 * (n_along - 1)
    # within one ring of the end loop: the faces of the first band only
    ring0 = phantoms.tube_end_loop(tube)
    near = metrics.host_dihedral_angles(tube.V, tube.F, ring0, rings=1)
    assert (np.abs(near - 60.0) <= 1e-9).sum() == 6
    # two rings reach the faces of the second band too
    near2 = metrics.host_dihedral_angles(tube.V, tube.F, ring0, rings=2)
    assert (np.abs(near2 - 60.0) <= 1e-9).sum() == 12


def test_ring_band():
    grid = _grid(5)
    corner = np.array([0])
    # the grid corner at vertex 0 is on both triangles of the first quad, and on no other
    assert metrics.ring_band(grid.F, corner, 1).sum() == 2
    two = metrics.ring_band(grid.F, corner, 2)
    assert two.sum() > 2 and two[metrics.ring_band(grid.F, corner, 1)].all()
    with pytest.raises(igljoin.OptionsError, match="rings"):
        metrics.ring_band(grid.F, corner, 0)
    with pytest.raises(igljoin.OptionsError, match="positive integer"):
        metrics.ring_band(grid.F, corner, 1.5)


# -- self-intersections -----------------------------------------------------------------------


def test_self_intersections_known_pairs():
    grid = _grid(3, size=2.0)  # 8 triangles in z = 0
    # a vertical triangle piercing the square at (0.3, 0.5), far from the grid's vertices
    spike = np.array([[0.3, 0.5, -1.0], [0.3, 0.5, 1.0], [0.35, 0.55, 1.0]])
    V = np.vstack([grid.V, spike])
    F = np.vstack([grid.F, [[9, 10, 11]]])
    pairs = metrics.self_intersections(V, F)
    # the spike crosses z = 0 in a short segment inside one grid triangle
    hit = [f for f in range(len(grid.F)) if _contains(V[F[f]], np.array([0.3, 0.5]))]
    assert pairs.tolist() == [[int(h), 8] for h in hit]
    # the same mesh tested only away from the spike: nothing
    away = np.ones(len(F), dtype=bool)
    away[8] = False
    assert len(metrics.self_intersections(V, F, away)) == 0
    # a clean flat mesh, whose neighbours share edges and vertices: nothing
    assert len(metrics.self_intersections(grid.V, grid.F)) == 0


def _contains(tri: np.ndarray, p: np.ndarray) -> bool:
    a, b, c = tri[:, :2]

    def side(u, v, q):
        return (v[0] - u[0]) * (q[1] - u[1]) - (v[1] - u[1]) * (q[0] - u[0]) >= 0

    return side(a, b, p) == side(b, c, p) == side(c, a, p)


# -- on joins ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def flat_rejoin():
    """A disk cut out of a flat grid, moved rigidly and joined back into its coplanar hole."""
    grid = _grid(21)
    cut = cut_piece(grid, center_vertex=10 * 21 + 10, radius=3.2)
    assert cut is not None
    moved = igljoin.Mesh(_rigid(cut.piece.V), cut.piece.F)
    res = igljoin.join(cut.host, moved, cut.host_curve, None, energy_tolerance=1e-10)
    return cut, res


def test_flat_patch_in_coplanar_hole_has_no_crease(flat_rejoin):
    cut, res = flat_rejoin
    m = res.metrics
    # 1e-5 degrees: both sides lie in z = 0 up to rounding, and arccos turns cosine
    # rounding into ~1e-6 degrees (see test_flat_mesh_has_zero_dihedral_angles)
    assert m["crease_deg"]["max"] <= 1e-5
    assert m["host_dihedral_deg"]["max"] <= 1e-5
    # the piece went back where it was: nothing stretched or moved (1e-9: the solve's
    # tolerance is 1e-10 and the start is already the minimum, so rounding only)
    assert abs(m["area_ratio"]["max"] - 1.0) <= 1e-9 and abs(m["area_ratio"]["min"] - 1.0) <= 1e-9
    assert max(abs(m["strain"]["max"]), abs(m["strain"]["min"])) <= 1e-9
    assert max(abs(m["vertex_strain"]["max"]), abs(m["vertex_strain"]["min"])) <= 1e-9
    assert m["displacement_nonrigid"]["max"] <= 1e-9 * cut.diameter
    n = cut.piece.n_vertices
    assert np.abs(res.guest.V[:n] - cut.piece.V).max() <= 1e-9 * cut.diameter
    assert m["folded_pairs"] == 0
    assert m["self_intersections"]["pairs"] == 0
    # welded back, it is the grid again
    merged = res.merged.mesh
    assert merged.n_vertices == 21 * 21 and merged.n_faces == 2 * 20 * 20


def test_report_has_every_metric_as_plain_json(flat_rejoin):
    _, res = flat_rejoin
    rep = json.loads(json.dumps(res.report(), allow_nan=False))
    m = rep["metrics"]
    for key in ("crease_deg", "host_dihedral_deg", "area_ratio", "strain", "vertex_strain"):
        assert set(m[key]) >= {"mean", "p95", "max"}, key
    assert set(m["displacement_nonrigid"]) >= {"mean", "p95", "max"}
    assert m["weld"]["ok"] is True
    assert m["self_intersections"]["rings"] == metrics.SELF_INTERSECTION_RINGS
    assert m["seam_gap"]["max"] <= 1e-12 * 10.0  # hard constraint on a 10-unit grid: rounding


def test_summaries_match_the_maps():
    s = phantoms.paper_sample("partial_patch", "shorter", resolution=0.5)
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    m, attrs = res.metrics, res.guest.vertex_attributes
    # the report summarises exactly the maps carried by the guest (same floats)
    assert m["vertex_strain"]["mean"] == float(np.nanmean(attrs["strain"]))
    assert m["displacement_nonrigid"]["max"] == float(attrs["displacement"].max())
    assert m["area_ratio"]["p95"] == float(np.percentile(res.area_ratio, 95))
    assert attrs["seam"].sum() == len(res.seam)
    # a shorter guest is stretched onto the host: positive mean strain everywhere it matters
    assert m["vertex_strain"]["mean"] > 0.0
    dih = metrics.host_dihedral_angles(s.host.V, s.host.F, s.host_curve)
    assert m["host_dihedral_deg"]["max"] == float(dih.max())


def test_guest_pushed_through_the_host_is_counted():
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    assert res.metrics["self_intersections"]["pairs"] == 0
    assert res.merged.n_splits == 0  # so host faces keep their ids in the merged mesh
    # a host face at the seam, and a guest edge (w, u) near the seam moved to pierce it
    host_face = int(np.flatnonzero(metrics.ring_band(s.host.F, s.host_curve, 1))[0])
    tri = s.host.V[s.host.F[host_face]]
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n /= np.linalg.norm(n)
    F = res.guest.F
    near = np.isin(F, res.seam).any(axis=1)
    w = int(np.setdiff1d(F[near], res.seam)[0])
    u = int(np.setdiff1d(F[(F == w).any(axis=1)], np.append(res.seam, w))[0])
    X = res.guest.V.copy()
    X[w] = tri.mean(axis=0) + 0.5 * n
    X[u] = tri.mean(axis=0) - 0.5 * n
    broken = dataclasses.replace(res, guest=igljoin.Mesh(X, F, res.guest.vertex_attributes))
    got = broken.measure_weld()["self_intersections"]
    # the two guest faces on edge (w, u) cross the host face at its centroid
    assert got["host_guest"] >= 2
    pairs = metrics.self_intersections(broken.merged.mesh.V, broken.merged.mesh.F)
    assert host_face in pairs.ravel()
