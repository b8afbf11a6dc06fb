"""Several seams in one solve, and tissue stiffness maps (issue: several seams, stiffness maps).

The welded bypass graft is checked with libigl and pymeshlab, not with
igljoin's own checks.
"""

from __future__ import annotations

import json

import igl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import igljoin
from igljoin import metrics, phantoms
from igljoin.stiffness import stiffness_from_regions
from igljoin.weld import GUEST, HOST

pymeshlab = pytest.importorskip("pymeshlab")  # independent topology checks


def _canonical(F: np.ndarray) -> np.ndarray:
    """Faces rotated so that their smallest vertex comes first (orientation kept)."""
    r = np.argmin(F, axis=1)
    return np.take_along_axis(F, (r[:, None] + np.arange(3)[None, :]) % 3, axis=1)


def _mean_edge(P: np.ndarray, closed: bool) -> float:
    seg = np.roll(P, -1, axis=0) - P if closed else np.diff(P, axis=0)
    return float(np.linalg.norm(seg, axis=1).mean())


@pytest.fixture(scope="module")
def graft():
    return phantoms.bypass_graft_sample()


#: Join angles of the issue (end-to-side grafts leave their vessel at 25-45 degrees).
ANGLES = (30.0, 45.0)


@pytest.fixture(scope="module", params=ANGLES, ids=lambda a: f"angle{a:g}")
def bypass(graft, request):
    """The graft joined end-to-side to the aorta and the coronary artery in one solve."""
    solver = igljoin.JoinSolver(
        graft.hosts, graft.guest, seams=graft.seams, join_angle=request.param
    )
    return solver, solver.solve()


# -- the bypass graft: both ends in one solve ---------------------------------------------------


def test_bypass_is_one_converged_solve(bypass):
    solver, res = bypass
    assert res.converged and res.stop_reason == "tolerance"
    assert solver.factorizations == 1
    assert len(res.seams) == 2 and res.counts["seams"] == 2
    # one fixed vertex set: every seam vertex of both seams, each once
    np.testing.assert_array_equal(solver.solver.fixed, res.seam)
    assert np.unique(res.seam).size == res.seam.size == sum(len(sm.seam) for sm in res.seams)


def test_bypass_seams_are_exact(bypass):
    _, res = bypass
    X, H = res.guest.V, res.host.V
    for sm in res.seams:
        h = _mean_edge(H[sm.host_curve], sm.closed)
        # 1e-9 of a host seam edge: the bound; the seams are hard constraints, so
        # only the rounding of the interpolated targets remains
        d = metrics.point_polyline_distance(X[sm.seam], H[sm.host_curve], sm.closed)
        assert d.max() <= 1e-9 * h
        # every host curve vertex is hit by its own guest vertex
        assert np.unique(sm.host_hit).size == len(sm.host_curve)
        assert np.abs(X[sm.guest_at_host] - H[sm.host_curve]).max() <= 1e-9 * h
    assert res.metrics["seam_gap"]["relative_max"] <= 1e-9


def test_bypass_leaves_each_wall_at_the_asked_angle(bypass):
    _, res = bypass
    angle = res.options.join_angle
    for k, sm in enumerate(res.seams):
        # the bound, on each seam separately: the mean band crease within 2 degrees
        # of the join angle (measured 0.2-0.6 degrees below it)
        assert abs(sm.crease.mean() - angle) <= 2.0, (k, sm.crease.mean())
        assert res.metrics["seams"][k]["crease_deg"]["mean"] == pytest.approx(sm.crease.mean())
    np.testing.assert_array_equal(res.crease, np.concatenate([sm.crease for sm in res.seams]))


def test_bypass_neither_intersects_nor_folds(bypass):
    _, res = bypass
    # the bound: none at all, of any kind (guest-guest, host-guest)
    assert res.metrics["self_intersections"]["pairs"] == 0
    assert res.metrics["folded_pairs"] == 0
    codes = {w.code for w in res.warnings}
    assert not codes & {"self_intersections", "folds", "area_change"}, codes


def test_an_opening_without_room_for_a_hood_is_reported():
    """Too steep for the opening: a graft sewn on its own oblique section pinches at 30 degrees."""
    g = phantoms.bypass_graft_sample(hood=0.0)
    res = igljoin.join(g.hosts, g.guest, seams=g.seams, join_angle=30.0)
    si = res.metrics["self_intersections"]
    assert si["pairs"] > 0 and res.metrics["folded_pairs"] > 0
    by_code = {w.code: w for w in res.warnings}
    assert by_code["self_intersections"].value == si["pairs"]
    assert f"{si['pairs']} pairs of faces" in by_code["self_intersections"].message
    assert by_code["folds"].value == res.metrics["folded_pairs"]
    # and where: every pair counted at the seam nearest to it, each seam's centre near
    # its own opening (nearer to its host curve than to the other seam's)
    assert sum(si["per_seam"]) == si["pairs"]
    for i, (count, centre) in enumerate(zip(si["per_seam"], si["centres"])):
        if count:
            assert f"seam {i}: {count} around" in by_code["self_intersections"].message
            curves = [res.host.V[sm.host_curve] for sm in res.seams]
            d = [np.linalg.norm(P - centre, axis=1).min() for P in curves]
            assert int(np.argmin(d)) == i


def test_bypass_seams_belong_to_their_hosts(bypass, graft):
    _, res = bypass
    off = res.host_offsets
    np.testing.assert_array_equal(off, np.cumsum([0] + [h.n_vertices for h in graft.hosts]))
    for sm, (index, loop, _) in zip(res.seams, graft.seams):
        assert sm.host_index == index
        assert off[index] <= sm.host_curve.min() and sm.host_curve.max() < off[index + 1]
        assert set((sm.host_curve - off[index]).tolist()) == set(loop.tolist())
    # the combined host is the hosts, in order
    np.testing.assert_array_equal(res.host.V, np.vstack([h.V for h in graft.hosts]))


def test_bypass_keeps_original_guest_vertices_first(bypass, graft):
    _, res = bypass
    n = graft.guest.n_vertices
    np.testing.assert_array_equal(res.rest_guest.V[:n], graft.guest.V)
    assert res.guest.n_vertices == n + res.counts["inserted"]
    # the second seam was refined after the first: its inserted vertices come later
    first, second = (sm.seam[sm.seam >= n] for sm in res.seams)
    assert len(first) == res.seams[0].inserted and len(second) == res.seams[1].inserted
    assert first.max() < second.min()


def test_bypass_welds_into_an_oriented_manifold(bypass, graft):
    _, res = bypass
    w = res.merged
    V, F = w.mesh.V, w.mesh.F
    assert igl.is_edge_manifold(F)[0]
    assert np.asarray(igl.is_vertex_manifold(F)).all()
    FF, comp = igl.bfs_orient(F)
    # re-orienting changes nothing (or flips the single component as a whole)
    assert np.unique(comp).size == 1
    same = (_canonical(FF) == _canonical(F)).all(axis=1)
    assert same.all() or not same.any()
    assert igl.doublearea(V, F).min() > 0.0
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    got = ms.get_topological_measures()
    assert got["non_two_manifold_edges"] == 0
    assert got["non_two_manifold_vertices"] == 0
    assert got["is_mesh_two_manifold"]
    # aorta + coronary + graft become one piece
    assert got["connected_components_number"] == 1
    assert not w.flipped_guest


def test_bypass_weld_shares_every_seam(bypass, graft):
    _, res = bypass
    w = res.merged
    k = sum(len(sm.host_curve) for sm in res.seams)
    s = len(res.seam)
    n_h = sum(h.n_vertices for h in graft.hosts)
    assert w.n_splits == s - k
    assert w.mesh.n_vertices == n_h + res.guest.n_vertices - k
    assert len(w.seams) == 2
    for sm, merged in zip(res.seams, w.seams):
        # each seam's guest vertices are merged vertices on that seam's host curve or its splits
        np.testing.assert_array_equal(
            w.source[merged[sm.host_hit]], np.c_[np.full(len(sm.host_curve), HOST), sm.host_curve]
        )
        split = np.setdiff1d(np.arange(len(sm.seam)), sm.host_hit)
        assert (w.source[merged[split], 0] == GUEST).all()


def test_bypass_joined_loops_are_gone(bypass, graft):
    _, res = bypass
    w = res.merged
    host_loops = sum(len(igljoin.boundary_loops(h.F)) for h in graft.hosts)
    guest_loops = len(igljoin.boundary_loops(res.guest.F))
    merged_loops = igljoin.boundary_loops(w.mesh.F)
    # two closed seams: each removes one host loop and one guest loop
    assert len(merged_loops) == host_loops + guest_loops - 2 * 2
    # what is left are exactly the loops that were not joined, host and guest
    as_source = [{tuple(p) for p in w.source[lp]} for lp in merged_loops]
    host_rest = [
        lp for lp in igljoin.boundary_loops(res.host.F) if not np.isin(lp, res.host_curve).any()
    ]
    guest_rest = [
        lp for lp in igljoin.boundary_loops(res.guest.F) if not np.isin(lp, res.seam).any()
    ]
    expected = [{(HOST, int(v)) for v in lp} for lp in host_rest]
    expected += [{(GUEST, int(v)) for v in lp} for lp in guest_rest]
    assert sorted(map(sorted, as_source)) == sorted(map(sorted, expected))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=w.mesh.V, face_matrix=w.mesh.F.astype(np.int32)))
    assert ms.get_topological_measures()["boundary_edges"] == sum(map(len, merged_loops))


def test_bypass_report_has_each_seam(bypass):
    _, res = bypass
    rep = json.loads(json.dumps(res.report(), allow_nan=False))
    assert [s["host_index"] for s in rep["seams"]] == [0, 1]
    assert len(rep["metrics"]["seams"]) == 2
    for s in rep["metrics"]["seams"]:
        assert s["seam_gap"]["relative_max"] <= rep["metrics"]["seam_gap"]["relative_max"]
    assert rep["metrics"]["weld"]["ok"] is True
    assert rep["metrics"]["weld"]["shared"] == len(res.seam)


def test_hosts_as_one_mesh_or_combined_indices_give_the_same_join(bypass, graft):
    _, ref = bypass
    off = ref.host_offsets
    one = igljoin.Mesh(ref.host.V, ref.host.F)  # one mesh with two components
    seams = [(loop + off[i], gc) for i, loop, gc in graft.seams]
    for host in (one, graft.hosts):
        res = igljoin.join(host, graft.guest, seams=seams, join_angle=ref.options.join_angle)
        np.testing.assert_array_equal(res.guest.V, ref.guest.V)
        np.testing.assert_array_equal(res.host_curve, ref.host_curve)
    assert [sm.host_index for sm in res.seams] == [0, 1]


def test_graft_is_not_twisted_and_its_placement_does_not_matter(graft):
    """Both ends' starts come from one rigid fit: the same join wherever the graft lies."""
    R = Rotation.from_rotvec([0.9, -0.4, 1.3]).as_matrix()
    moved = igljoin.Mesh(graft.guest.V @ R.T + [40.0, -25.0, 10.0], graft.guest.F)
    opts = dict(smooth=False, energy_tolerance=1e-9)  # the seams' pairing alone, converged tightly
    a = igljoin.join(graft.hosts, graft.guest, seams=graft.seams, **opts)
    b = igljoin.join(graft.hosts, moved, seams=graft.seams, **opts)
    for sa, sb in zip(a.seams, b.seams):
        np.testing.assert_array_equal(sa.seam, sb.seam)
    size = float(np.linalg.norm(np.ptp(graft.guest.V, axis=0)))
    # 1e-5 of the graft's size: the same minimum from two placements (rounding of the
    # rigid pre-alignment, amplified by the iteration), as for a single seam
    assert np.abs(a.guest.V - b.guest.V).max() <= 1e-5 * size
    # an untwisted graft sewn on without the smooth term neither folds nor intersects itself
    assert a.metrics["folded_pairs"] == 0
    assert a.metrics["self_intersections"]["pairs"] == 0


def test_new_targets_reuse_the_factorization(bypass):
    solver, res = bypass
    moved = solver.solve(targets=res.seam_targets + [0.0, 0.0, 0.25], max_iterations=3)
    assert solver.factorizations == 1
    # hard constraints: the targets are held exactly (only rounding of the solve)
    np.testing.assert_allclose(moved.guest.V[moved.seam], res.seam_targets + [0, 0, 0.25])
    stops = np.cumsum([len(sm.seam) for sm in moved.seams])
    for sm, start, stop in zip(moved.seams, stops - stops[0], stops):
        np.testing.assert_array_equal(sm.targets, moved.seam_targets[start:stop])
    assert moved.metrics["weld"]["ok"] is False
    assert "seam 0:" in moved.metrics["weld"]["error"]


# -- one seam through the several-seam API ------------------------------------------------------


@pytest.fixture(scope="module")
def patch():
    return phantoms.paper_sample("partial_patch", "shorter", resolution=0.5)


def test_single_seam_is_identical_through_every_api(patch):
    s = patch
    hc, gc = s.host_curve, s.guest_curve
    ref = igljoin.join(s.host, s.guest, hc, gc)
    same = [
        igljoin.join(s.host, s.guest, seams=[(hc, gc)]),
        igljoin.join(s.host, s.guest, seams=[(0, hc, gc)]),
        igljoin.join([s.host], s.guest, seams=[(0, hc, gc)]),
        igljoin.join(s.host, s.guest, hc, gc, stiffness=np.ones(s.guest.n_vertices)),
        igljoin.join(s.host, s.guest, hc, gc, stiffness=np.ones(s.guest.n_faces)),
    ]
    for res in same:
        # exact equality: the same code path and the same arithmetic
        np.testing.assert_array_equal(res.guest.V, ref.guest.V)
        np.testing.assert_array_equal(res.guest.F, ref.guest.F)
        np.testing.assert_array_equal(res.seam, ref.seam)
        np.testing.assert_array_equal(res.host_curve, ref.host_curve)
        np.testing.assert_array_equal(res.crease, ref.crease)
        np.testing.assert_array_equal(res.merged.mesh.V, ref.merged.mesh.V)
        np.testing.assert_array_equal(res.merged.mesh.F, ref.merged.mesh.F)
        assert res.iterations == ref.iterations
    (sm,) = ref.seams
    np.testing.assert_array_equal(sm.seam, ref.seam)
    np.testing.assert_array_equal(sm.crease, ref.crease)
    np.testing.assert_array_equal(sm.host_hit, ref.correspondence.host_hit)
    assert ref.metrics["seams"][0]["seam_gap"] == ref.metrics["seam_gap"]


# -- stiffness maps ------------------------------------------------------------------------------


def test_stiff_half_of_a_patch_stretches_less():
    s, k = phantoms.stiff_patch_sample(stiff=10)
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, stiffness=k)
    assert res.converged
    change = np.abs(res.area_ratio - 1.0)
    stiff = k[res.correspondence.face_parent] > 1.0  # refined faces inherit their parent's k
    # the bound: the 10x stiffer half changes its area at most half as much
    assert np.median(change[stiff]) <= 0.5 * np.median(change[~stiff])


def test_stiffness_from_an_attribute_of_a_ply_file(patch, tmp_path):
    s = patch
    _, k = phantoms.stiff_patch_sample(stiff=10, resolution=0.5)
    kv = np.linspace(0.5, 4.0, s.guest.n_vertices)
    guest = s.guest.with_attributes(vertex={"elastic": kv}, face={"stiffness": k})
    path = igljoin.write_mesh(tmp_path / "guest.ply", guest)
    back = igljoin.read_mesh(path)
    args = (s.host, back, s.host_curve, s.guest_curve)
    by_face = igljoin.join(*args, stiffness="stiffness")
    by_vertex = igljoin.join(*args, stiffness="elastic")
    # PLY stores float64: the attribute is the array, exactly
    np.testing.assert_array_equal(
        by_face.guest.V, igljoin.join(*args, stiffness=k, stiffness_on="face").guest.V
    )
    np.testing.assert_array_equal(
        by_vertex.guest.V, igljoin.join(*args, stiffness=kv, stiffness_on="vertex").guest.V
    )
    np.testing.assert_array_equal(by_face.options.stiffness, k)
    assert by_face.options.stiffness_on == "face"
    # a solver changes its map by name too (a new factorization)
    solver = igljoin.JoinSolver(*args, stiffness="elastic")
    again = solver.solve(stiffness="stiffness")
    assert solver.factorizations == 2 and solver.options.stiffness_on == "face"
    np.testing.assert_array_equal(again.guest.V, by_face.guest.V)


def test_stiffness_regions(patch):
    s = patch
    n = s.guest.n_vertices
    z = s.guest.V[:, 2]  # the patch's long axis (it lies in a plane x = const)
    half = np.flatnonzero(z > np.median(z))
    regions = [(half, 10.0), (half[:5], 0.5)]
    k = stiffness_from_regions(n, regions)
    assert k.shape == (n,)
    assert (k[half[:5]] == 0.5).all()  # the later region wins
    assert (k[half[5:]] == 10.0).all()
    assert (np.delete(k, half) == 1.0).all()
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    a = igljoin.join(*args, stiffness_regions=regions)
    b = igljoin.join(*args, stiffness=k)
    np.testing.assert_array_equal(a.guest.V, b.guest.V)
    mask = np.zeros(n, dtype=bool)
    mask[half] = True
    np.testing.assert_array_equal(
        stiffness_from_regions(n, [(mask, 3.0)], default=2.0), np.where(mask, 3.0, 2.0)
    )
    assert igljoin.stiffness_from_regions is stiffness_from_regions


# -- bad input -----------------------------------------------------------------------------------


def test_seams_and_single_curves_do_not_mix(patch):
    s = patch
    with pytest.raises(igljoin.CurveError, match="not both"):
        igljoin.join(s.host, s.guest, s.host_curve, seams=[(s.host_curve, s.guest_curve)])


def test_seams_sharing_guest_vertices_are_refused(graft):
    (i, a, g0), (j, b, _) = graft.seams
    with pytest.raises(igljoin.CurveError, match=r"seams\[0\] and seams\[1\] share 40 guest"):
        igljoin.join(graft.hosts, graft.guest, seams=[(i, a, g0), (j, b, g0)])


def test_seams_sharing_host_vertices_are_refused(graft):
    (i, a, g0), (_, _, g1) = graft.seams
    with pytest.raises(igljoin.CurveError, match=r"share 56 host vertices .*one seam only"):
        igljoin.join(graft.hosts, graft.guest, seams=[(i, a, g0), (i, a, g1)])


def test_overlapping_open_seams_are_refused(patch):
    s = patch
    hole = s.host_curve
    loop = igljoin.boundary_loops(s.guest.F)[0]
    seams = [(hole[0:10], loop[0:10]), (hole[20:30], loop[5:15])]
    with pytest.raises(igljoin.CurveError, match=r"share 5 guest vertices \(\[") as e:
        igljoin.join(s.host, s.guest, seams=seams)
    assert "neither overlap nor touch" in str(e.value)


@pytest.mark.parametrize(
    ("seams", "match"),
    [
        ([], "non-empty list"),
        ("loop", "non-empty list"),
        ([(1,)], r"seams\[0\] must be"),
        ([("0", None, None)], "host index and must be an integer"),
        ([(2, None, None)], "host index 2 does not exist; there are 2 host meshes"),
    ],
)
def test_malformed_seams(graft, seams, match):
    with pytest.raises(igljoin.CurveError, match=match):
        igljoin.join(graft.hosts, graft.guest, seams=seams)


def test_host_index_needs_a_list_of_hosts(patch):
    s = patch
    with pytest.raises(igljoin.CurveError, match="one host mesh .* pass host=\\[mesh0"):
        igljoin.join(s.host, s.guest, seams=[(1, s.host_curve, s.guest_curve)])


def test_unknown_stiffness_attribute_lists_the_available_ones(patch):
    s = patch
    guest = s.guest.with_attributes(vertex={"elastic": np.ones(s.guest.n_vertices)})
    with pytest.raises(
        igljoin.OptionsError,
        match=r"no attribute of that name; available: "
        r"vertex 'elastic'",
    ) as e:
        igljoin.join(s.host, guest, s.host_curve, s.guest_curve, stiffness="elasticity")
    assert "'elasticity'" in str(e.value)
    with pytest.raises(igljoin.OptionsError, match="available: none"):
        igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, stiffness="k")


def test_bad_stiffness_regions(patch):
    s = patch
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    n = s.guest.n_vertices
    with pytest.raises(igljoin.OptionsError, match="not both"):
        igljoin.join(*args, stiffness=np.ones(n), stiffness_regions=[([0], 2.0)])
    with pytest.raises(igljoin.OptionsError, match=r"stiffness_regions\[0\] k=0.0 must be"):
        igljoin.join(*args, stiffness_regions=[([0], 0.0)])
    with pytest.raises(igljoin.OptionsError, match=f"range over \\[0, {n}\\]"):
        igljoin.join(*args, stiffness_regions=[([0, n], 2.0)])
    with pytest.raises(igljoin.OptionsError, match="must be a pair"):
        igljoin.join(*args, stiffness_regions=[[0, 1, 2]])
    with pytest.raises(igljoin.OptionsError, match="per vertex"):
        igljoin.join(*args, stiffness_regions=[([0], 2.0)], stiffness_on="face")
