"""The join engine on the paper's six samples and beyond (issue: core join engine)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import igljoin
from igljoin import metrics, phantoms

SAMPLES = [(sc, ln) for sc in ("end_to_end", "partial_patch") for ln in phantoms.LENGTH_RATIOS]


@pytest.fixture(scope="module")
def paper_results():
    """Each paper sample joined with and without the smooth-join term."""
    out = {}
    for scenario, length in SAMPLES:
        s = phantoms.paper_sample(scenario, length)
        solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
        with_smooth = solver.solve()
        without = solver.solve(smooth=False)
        out[(scenario, length)] = (s, with_smooth, without)
    return out


def _host_edge(res: igljoin.JoinResult) -> float:
    P = res.host.V[res.host_curve]
    seg = np.roll(P, -1, axis=0) - P if res.closed else np.diff(P, axis=0)
    return float(np.linalg.norm(seg, axis=1).mean())


def assert_exact_seam(res: igljoin.JoinResult) -> None:
    """Seam vertices on the host curve; host curve vertices hit by seam vertices."""
    h = _host_edge(res)
    # 1e-9 of a seam edge: the bound; the seam is a hard constraint, so
    # only floating-point rounding of the interpolated targets remains
    d = metrics.point_polyline_distance(
        res.guest.V[res.seam], res.host.V[res.host_curve], res.closed
    )
    assert d.max() <= 1e-9 * h
    hit = res.guest.V[res.guest_at_host]
    assert np.abs(hit - res.host.V[res.host_curve]).max() <= 1e-9 * h


@pytest.mark.parametrize("key", SAMPLES, ids=["/".join(k) for k in SAMPLES])
def test_exact_seam_on_paper_samples(paper_results, key):
    _, res, res0 = paper_results[key]
    assert_exact_seam(res)
    assert_exact_seam(res0)
    assert res.converged and res0.converged


@pytest.mark.parametrize("key", SAMPLES, ids=["/".join(k) for k in SAMPLES])
def test_smooth_join_removes_the_crease(paper_results, key):
    _, res, res0 = paper_results[key]
    smooth, plain = res.crease.mean(), res0.crease.mean()
    # the bounds: below 2 degrees and at least 5x smaller than without the term
    assert smooth < 2.0
    assert smooth * 5.0 <= plain


@pytest.mark.parametrize("key", SAMPLES, ids=["/".join(k) for k in SAMPLES])
def test_no_folded_triangles(paper_results, key):
    _, res, res0 = paper_results[key]
    assert res.metrics["folded_pairs"] == 0
    assert res0.metrics["folded_pairs"] == 0


@pytest.mark.parametrize("scenario", ["end_to_end", "partial_patch"])
def test_paper_observations(paper_results, scenario):
    shorter = paper_results[(scenario, "shorter")][1]
    equal = paper_results[(scenario, "equal")][1]
    longer = paper_results[(scenario, "longer")][1]
    # equal boundaries: minimally deformed (issue bound: median |ratio - 1| <= 2 %)
    assert np.median(np.abs(equal.area_ratio - 1.0)) <= 0.02
    # a shorter guest is stretched: more area than it had
    assert shorter.metrics["area_ratio"]["total"] > 1.0
    # a longer guest (boundary ratio 1.25) bulges instead of shrinking: it keeps at
    # least 90 % of its area (shrinking its boundary to the host's would leave ~64 %)
    assert longer.metrics["area_ratio"]["total"] >= 0.9


def test_counts_follow_the_paper(paper_results):
    _, res, res0 = paper_results[("end_to_end", "equal")]
    c = res.counts
    assert c["points"] == res.guest.n_vertices == res.rest_guest.n_vertices
    assert c["hard"] == 3 * len(res.seam)
    # paper: 2,494 points / 522 hard / 29,688 soft for its end-to-end sample; ours is
    # built to the same size, so within 10 % (the meshes differ in detail)
    assert abs(c["points"] - 2494) <= 0.1 * 2494
    assert abs(c["hard"] - 522) <= 0.1 * 522
    assert abs(c["soft"] - 29688) <= 0.1 * 29688
    # without the smooth term there are fewer soft constraints
    assert res0.counts["soft"] < c["soft"]


def test_deformed_guest_keeps_original_vertices_first(paper_results):
    s, res, _ = paper_results[("end_to_end", "shorter")]
    n = s.guest.n_vertices
    assert res.guest.n_vertices == n + res.counts["inserted"]
    # rest guest: original vertices unchanged, in order
    np.testing.assert_array_equal(res.rest_guest.V[:n], s.guest.V)
    assert res.area_ratio.shape == (res.guest.n_faces,)
    np.testing.assert_array_equal(res.guest.face_attributes["area_ratio"], res.area_ratio)


def test_report_is_plain_json(paper_results):
    _, res, _ = paper_results[("partial_patch", "equal")]
    rep = json.loads(json.dumps(res.report()))
    assert rep["converged"] is True
    assert rep["counts"]["points"] == res.counts["points"]
    assert rep["metrics"]["crease_deg"]["mean"] == pytest.approx(res.crease.mean())
    assert set(rep["timings"]) >= {"factor", "local", "back_solve", "total"}


def _rigid(V, R, t):
    return np.asarray(V) @ R.T + t


def test_rigid_motion_of_both_moves_the_result_the_same_way():
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    R = Rotation.from_rotvec([0.4, -0.7, 0.3]).as_matrix()
    t = np.array([12.0, -30.0, 7.0])
    host2 = igljoin.Mesh(_rigid(s.host.V, R, t), s.host.F)
    guest2 = igljoin.Mesh(_rigid(s.guest.V, R, t), s.guest.F)
    opts = dict(energy_tolerance=1e-9, max_iterations=2000)
    a = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, **opts)
    b = igljoin.join(host2, guest2, s.host_curve, s.guest_curve, **opts)
    size = float(np.linalg.norm(np.ptp(s.guest.V, axis=0)))
    # 1e-6 relative: the bound; the steps are rigid-motion equivariant and
    # converged tightly, so only rounding separates the two runs
    assert np.abs(_rigid(a.guest.V, R, t) - b.guest.V).max() <= 1e-6 * size
    np.testing.assert_array_equal(a.seam, b.seam)


def test_guest_placement_does_not_matter():
    """Rotation-aware shape term: moving only the guest leaves the result unchanged."""
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    R = Rotation.from_rotvec([1.0, 0.5, -0.2]).as_matrix()
    moved = igljoin.Mesh(_rigid(s.guest.V, R, [5.0, 2.0, -8.0]), s.guest.F)
    opts = dict(energy_tolerance=1e-9, max_iterations=2000)
    a = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, **opts)
    b = igljoin.join(s.host, moved, s.host_curve, s.guest_curve, **opts)
    size = float(np.linalg.norm(np.ptp(s.guest.V, axis=0)))
    # 1e-5 of the guest size: the same minimum reached from two starting placements
    # (rounding of the rigid pre-alignment, amplified by the iteration)
    assert np.abs(a.guest.V - b.guest.V).max() <= 1e-5 * size


def test_open_curve_join():
    s = phantoms.paper_sample("open_strip", "equal")
    assert not s.closed
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    res0 = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth=False)
    assert not res.closed
    assert_exact_seam(res)
    # start meets start, end meets end
    assert res.guest_at_host[0] == s.guest_curve[0]
    assert res.guest_at_host[-1] == s.guest_curve[-1]
    # same bounds as the closed samples
    assert res.crease.mean() < 2.0
    assert res.crease.mean() * 5.0 <= res0.crease.mean()


def test_open_curve_by_start_and_end_vertices():
    s = phantoms.paper_sample("open_strip", "shorter")
    hc = igljoin.Curve(start=int(s.host_curve[0]), end=int(s.host_curve[-1]))
    gc = igljoin.Curve(start=int(s.guest_curve[0]), end=int(s.guest_curve[-1]))
    res = igljoin.join(s.host, s.guest, hc, gc)
    np.testing.assert_array_equal(res.host_curve, s.host_curve)
    assert_exact_seam(res)


@pytest.mark.parametrize("scenario", ["end_to_end", "partial_patch"])
def test_guest_much_coarser_than_host(scenario):
    s = phantoms.paper_sample(scenario, "equal", guest_resolution=0.2)
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    assert res.counts["inserted"] > 0.5 * len(s.host_curve)
    assert_exact_seam(res)
    assert res.metrics["folded_pairs"] == 0
    # same bound as the paper samples
    assert res.crease.mean() < 2.0


def test_paper_variants_work():
    """The paper's literal Eq. 7 and its fixed (not rotated) Laplacian are available."""
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    base = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth=False)
    paper = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode="paper")
    fixed = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, rotation_aware=False)
    cot = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, laplacian="cotangent")
    for res in (paper, fixed, cot):
        assert_exact_seam(res)
        assert res.crease.mean() < base.crease.mean()


def test_uniform_stiffness_equals_default_and_maps_are_accepted():
    s = phantoms.paper_sample("partial_patch", "shorter", resolution=0.5)
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    ref = igljoin.join(*args)
    ones_v = igljoin.join(*args, stiffness=np.ones(s.guest.n_vertices))
    ones_f = igljoin.join(*args, stiffness=np.ones(s.guest.n_faces))
    np.testing.assert_array_equal(ref.guest.V, ones_v.guest.V)
    np.testing.assert_array_equal(ref.guest.V, ones_f.guest.V)
    stiff = igljoin.join(*args, stiffness=np.full(s.guest.n_vertices, 10.0))
    # a 10x stiffer guest stretches less when forced onto a longer boundary
    assert np.median(np.abs(stiff.area_ratio - 1)) < np.median(np.abs(ref.area_ratio - 1))


def test_solver_reuses_its_factorization():
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    first = solver.solve()
    again = solver.solve(max_iterations=5, energy_tolerance=1e-3)
    moved = solver.solve(targets=first.seam_targets + [0.0, 0.0, 0.5])
    assert solver.factorizations == 1
    assert again.iterations <= 5
    # new targets are held exactly (hard constraints)
    np.testing.assert_allclose(moved.guest.V[moved.seam], first.seam_targets + [0, 0, 0.5])
    solver.solve(smooth_weight=2.0)
    assert solver.factorizations == 2


def test_time_limit_and_iteration_limit_return_unconverged_results():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    res = igljoin.join(*args, max_iterations=2)
    assert not res.converged and res.iterations == 2 and res.stop_reason == "max_iterations"
    res = igljoin.join(*args, time_limit=1e-9)
    assert not res.converged and res.stop_reason == "time_limit"
    assert np.isfinite(res.guest.V).all()


def test_inputs_are_never_modified():
    s = phantoms.paper_sample("partial_patch", "shorter", resolution=0.5)
    Vh, Fh = np.array(s.host.V), np.array(s.host.F)
    Vg, Fg = np.array(s.guest.V), np.array(s.guest.F).astype(np.int32)
    copies = [a.copy() for a in (Vh, Fh, Vg, Fg)]
    curve = np.array(s.host_curve)
    curve_copy = curve.copy()
    igljoin.join((Vh, Fh), (Vg, Fg), curve)
    for a, b in zip((Vh, Fh, Vg, Fg), copies):
        np.testing.assert_array_equal(a, b)
        assert a.flags.writeable
    np.testing.assert_array_equal(curve, curve_copy)


# -- bad input ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def patch():
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.4)


def _join(host, guest, hc=None, gc=None, **kw):
    return igljoin.join(host, guest, hc, gc, **kw)


def test_bad_shapes_and_values(patch):
    V, F = patch.guest.V, patch.guest.F
    with pytest.raises(igljoin.MeshError, match=r"\(n, 3\)"):
        _join(patch.host, (V[:, :2], F), patch.host_curve)
    with pytest.raises(igljoin.MeshError, match="cannot be converted"):
        _join(patch.host, ([["a", "b", "c"]], F), patch.host_curve)
    bad = np.array(V)
    bad[5] = np.nan
    with pytest.raises(igljoin.MeshError, match="NaN or infinite"):
        _join(patch.host, (bad, F), patch.host_curve)
    with pytest.raises(igljoin.MeshError, match="range"):
        _join(patch.host, (V, np.vstack([F, [[0, 1, len(V)]]])), patch.host_curve)
    with pytest.raises(igljoin.MeshError, match="expected an igljoin.Mesh"):
        _join(patch.host, "guest.ply", patch.host_curve)


def test_degenerate_and_non_manifold_faces(patch):
    V, F = patch.guest.V, patch.guest.F
    with pytest.raises(igljoin.MeshError, match="repeat a vertex"):
        _join(patch.host, (V, np.vstack([F, [[0, 0, 1]]])), patch.host_curve)
    a, b, c = F[10]
    extra = np.vstack([V, V[[a, b]].mean(axis=0) + [0, 0, 1.0]])
    nm = np.vstack([F, [[a, b, len(V)]]])
    with pytest.raises(igljoin.MeshError, match="more than two faces"):
        _join(patch.host, (extra, nm), patch.host_curve)


def test_curve_errors(patch):
    host = patch.host
    interior = int(
        np.setdiff1d(np.arange(host.n_vertices), np.concatenate(igljoin.boundary_loops(host.F)))[0]
    )
    with pytest.raises(igljoin.CurveError, match="not on a boundary"):
        _join(host, patch.guest, [interior, interior + 1])
    loops = igljoin.boundary_loops(host.F)
    with pytest.raises(igljoin.CurveError, match="on loop"):
        _join(host, patch.guest, igljoin.Curve(start=int(loops[0][0]), end=int(loops[1][0])))
    # open host curve against the patch's closed loop
    with pytest.raises(igljoin.CurveError, match="both curves must be closed"):
        _join(host, patch.guest, igljoin.Curve(start=int(loops[1][0]), end=int(loops[1][5])))


def test_guest_without_free_vertex(patch):
    # a guest that is only its seam: a fan of triangles on the boundary loop alone
    loop = patch.host_curve
    P = patch.host.V[loop]
    k = len(loop)
    F = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], axis=1)
    with pytest.raises(igljoin.SolveError, match="no free vertex"):
        _join(patch.host, (P + [1.0, 0, 0], F), patch.host_curve)


def test_guest_component_off_the_seam(patch):
    V, F = patch.guest.V, patch.guest.F
    far = V[F[:3]].reshape(-1, 3) + [0.0, 0.0, 50.0]
    V2 = np.vstack([V, far])
    F2 = np.vstack([F, np.arange(len(V), len(V) + 9).reshape(3, 3)])
    loops = igljoin.boundary_loops(F2)
    main = next(k for k, lp in enumerate(loops) if len(lp) == len(igljoin.boundary_loops(F)[0]))
    with pytest.raises(igljoin.SolveError, match="do not touch the seam"):
        _join(patch.host, (V2, F2), patch.host_curve, igljoin.Curve(loop=main))


def test_option_errors_name_the_option(patch):
    with pytest.raises(igljoin.OptionsError, match="smooth_weight"):
        _join(patch.host, patch.guest, patch.host_curve, smooth_weight=-1)
    with pytest.raises(igljoin.OptionsError, match="max_iterations"):
        _join(patch.host, patch.guest, patch.host_curve, max_iterations=0)
    with pytest.raises(igljoin.OptionsError, match="unknown join options"):
        _join(patch.host, patch.guest, patch.host_curve, smoth=True)
    with pytest.raises(igljoin.OptionsError, match="stiffness has"):
        _join(patch.host, patch.guest, patch.host_curve, stiffness=np.ones(7))


def test_paper_samples_at_their_sizes_join_smoothly_by_the_band_measure():
    """Issue 2's creases, by the band measure: mean <= 0.5 deg with the smooth term."""
    for s in phantoms.paper_samples():
        res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
        plain = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth=False)
        assert res.converged, s.name
        # the bar of issue 2 (measured 0.23-0.43 deg at the paper's sizes)
        assert res.metrics["crease_deg"]["mean"] <= 0.5, s.name
        # and far below the crease the guest arrives at (3.5-61 deg measured)
        assert 5.0 * res.metrics["crease_deg"]["mean"] <= plain.metrics["crease_deg"]["mean"]
        assert res.metrics["folded_pairs"] == 0, s.name


def test_smooth_term_never_worse_on_a_guest_that_already_joins_smoothly():
    """A guest joined once joins again: with the smooth term its crease is not above without."""
    for length in ("shorter", "equal", "longer"):
        s = phantoms.paper_sample("partial_patch", length, resolution=0.5)
        first = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
        again = igljoin.join(first.host, first.guest, first.host_curve, None)
        plain = igljoin.join(first.host, first.guest, first.host_curve, None, smooth=False)
        # the band measure is the same function of the same surfaces in both: any rise is the
        # term's doing; 0.05 deg is the smallest crease the term removes at all
        assert again.metrics["crease_deg"]["mean"] <= plain.metrics["crease_deg"]["mean"] + 0.05


def test_join_angle_zero_is_the_smooth_join_exactly():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    default = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    zero = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, join_angle=0.0)
    np.testing.assert_array_equal(zero.guest.V, default.guest.V)
    assert [w.code for w in zero.warnings] == [w.code for w in default.warnings]
