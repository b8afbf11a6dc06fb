"""The fast paths of the metrics phase give exactly what the plain computations give.

The metrics, the weld and its self-intersection count were sped up by
computing on contiguous coordinate arrays, on the faces at a curve only, on
cached host values, on candidate pairs instead of all pairs, with the manifold
checks of :mod:`igljoin.topology` instead of libigl's, and with a floating-point
pre-check that keeps clean faces away from CGAL; a summary sorts its values once,
and a band fit builds its design columns and normal equations in compiled loops
that take the einsums' products and sums in order. Each test runs a fast path next
to a reference computation (the plain code it replaced, kept below, or libigl /
CGAL themselves) and compares. Tolerances are zero throughout: the fast paths perform the same
floating-point operations in the same order (or select among identical
values), so every float is compared bit for bit and every count exactly.
"""

from __future__ import annotations

import dataclasses
import importlib

import igl
import igl.copyleft.cgal as cgal
import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import bandfit, correspond, frames, metrics, phantoms, topology
from igljoin.mesh import Mesh
from igljoin.seam_geometry import SeamGeometry

weld_mod = importlib.import_module("igljoin.weld")

PAPER = [
    (sc, ln) for sc in ("end_to_end", "partial_patch") for ln in ("shorter", "equal", "longer")
]


@pytest.fixture(scope="module")
def joins():
    """The six paper samples, joined (at half resolution, to keep the module quick)."""
    out = {}
    for key in PAPER:
        s = phantoms.paper_sample(*key, resolution=0.5)
        out[key] = (s, igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve))
    return out


def _assert_same(a, b):
    """Bit-for-bit equality of two arrays (same shape and dtype; NaN equals NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


# -- reference computations (the code the fast paths replaced) --------------------------------


def _ref_face_normals_areas(V, F):
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a = np.linalg.norm(c, axis=1)
    return c / np.where(a > 0, a, 1.0)[:, None], 0.5 * a


def _ref_ring_band(F, vertices, rings):
    mark = np.zeros(max(F.max(), vertices.max()) + 1, dtype=bool)
    mark[vertices] = True
    band = mark[F].any(axis=1)
    for _ in range(rings - 1):
        mark[F[band].reshape(-1)] = True
        band = mark[F].any(axis=1)
    return band


def _ref_adjacent_face_pairs(F):
    m = len(F)
    n = int(F.max()) + 1
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


def _ref_seam_frames(V, F, curve, closed, radius=None, curve_points=None):
    """seam_frames over all faces through the sparse incidence matrix, as it was."""
    P = V[curve] if curve_points is None else curve_points
    normals, areas = _ref_face_normals_areas(V, F)
    W = frames.vertex_face_matrix(F, len(V))[curve].multiply(areas[None, :]).tocsr()
    n = frames.unit(W @ normals)
    span = 1
    if radius is not None and radius > 0:
        seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
        span = int(np.clip(round(radius / max(float(seg.mean()), 1e-300)), 1, max(1, len(P) // 4)))
    T = frames._curve_tangents(P, closed, span)
    if radius is not None and radius > 0:
        n = frames._quadric_normals(V, P, n, T, radius)
    h = frames.unit(np.cross(n, T))
    centroid_offset = (W @ V[F].mean(axis=1)) / np.maximum(np.asarray(W.sum(axis=1)), 1e-300) - P
    flip = np.einsum("ij,ij->i", h, centroid_offset) < 0
    h[flip] *= -1.0
    return frames.SeamFrames(normal=n, tangent=T, inward=h)


def _ref_rigid_fit(A, B):
    """Kabsch in one piece: the proper rotation and translation fitting A onto B."""
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    H = (A - ca).T @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, cb - ca @ R.T


def _ref_point_polyline_distance(P, C, closed):
    B = np.roll(C, -1, axis=0) if closed else C[1:]
    A = C[: len(B)]
    AB = B - A
    ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    t = np.clip(np.einsum("pkj,kj->pk", P[:, None, :] - A[None], AB) / ab2, 0.0, 1.0)
    D = A[None] + t[..., None] * AB[None] - P[:, None, :]
    return np.sqrt(np.einsum("pkj,pkj->pk", D, D).min(axis=1))


def _cgal_pairs(V, F, faces=None):
    """Self-intersecting pairs straight from CGAL, on every tested face."""
    sel = np.arange(len(F)) if faces is None else np.flatnonzero(faces)
    if sel.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    used, local = np.unique(F[sel], return_inverse=True)
    pairs = cgal.remesh_self_intersections(
        np.ascontiguousarray(V[used], dtype=np.float64),
        np.ascontiguousarray(local.reshape(-1, 3).astype(np.int64)),
        detect_only=True,
    )[2]
    pairs = np.sort(sel[np.asarray(pairs, dtype=np.int64).reshape(-1, 2)], axis=1)
    return np.unique(pairs, axis=0) if len(pairs) else pairs


def _random_soup(rng, n_faces, n_vertices, scale):
    """Faces on shared random vertices, crossing each other often."""
    V = rng.normal(size=(n_vertices, 3)) * scale
    F = np.array([rng.choice(n_vertices, 3, replace=False) for _ in range(n_faces)])
    return V, F


# -- floating-point kernels -------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_face_normals_areas_match_the_row_wise_formulation(joins, dtype):
    rng = np.random.default_rng(0)
    V = (rng.normal(size=(400, 3)) * 10.0 ** rng.uniform(-4, 4, size=(400, 1))).astype(dtype)
    F = rng.integers(0, 400, size=(2000, 3))
    F[:50, 2] = F[:50, 0]  # zero-area faces get zero normals
    meshes = [(V, F)] + [(r.guest.V.astype(dtype), r.guest.F) for _, r in joins.values()]
    for V, F in meshes:
        N, A = frames.face_normals_areas(V, F)
        N0, A0 = _ref_face_normals_areas(V, F)
        _assert_same(N, N0)
        _assert_same(A, A0)
        _assert_same(frames.face_areas(V, F), A0)


def test_edge_strain_and_displacement_match_row_norms(joins):
    for _, res in joins.values():
        V0, V1, F = res.rest_guest.V, res.guest.V, res.guest.F
        E = np.asarray(igl.edges(F), dtype=np.int64)
        l0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
        l1 = np.linalg.norm(V1[E[:, 0]] - V1[E[:, 1]], axis=1)
        _assert_same(metrics.edge_strain(V0, V1, E), (l1 - l0) / np.where(l0 > 0, l0, np.nan))
        R, t = _ref_rigid_fit(V0, V1)
        _assert_same(
            metrics.nonrigid_displacement(V0, V1), np.linalg.norm(V1 - (V0 @ R.T + t), axis=1)
        )
        ratio = metrics.area_ratio(V0, V1, F)
        a0, a1 = _ref_face_normals_areas(V0, F)[1], _ref_face_normals_areas(V1, F)[1]
        _assert_same(ratio, a1 / np.where(a0 > 0, a0, np.nan))


def test_ring_band_matches_the_any_loop(joins):
    rng = np.random.default_rng(1)
    for _, res in joins.values():
        F = res.merged.mesh.F
        for rings in (1, 2, 3, 4):
            _assert_same(
                metrics.ring_band(F, res.merged.seam, rings),
                _ref_ring_band(F, res.merged.seam, rings),
            )
        some = rng.choice(F.max() + 1, 7, replace=False)
        _assert_same(metrics.ring_band(F, some, 2), _ref_ring_band(F, some, 2))


def test_adjacent_face_pairs_keep_the_stable_order():
    rng = np.random.default_rng(2)
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    extra = s.guest.F[rng.integers(0, s.guest.n_faces, 20)]
    # with repeated faces some edges carry 3 or 4 faces: several pairs per edge
    for F in (
        s.guest.F,
        np.vstack([s.guest.F, extra, extra[:, ::-1]]),
        rng.integers(0, 9, (60, 3)),
    ):
        got, ref = metrics._adjacent_face_pairs(F), _ref_adjacent_face_pairs(F)
        _assert_same(got[0], ref[0])
        _assert_same(got[1], ref[1])
    # the fall-back for keys whose packed form would overflow int64
    key = rng.integers(0, 5, 100)
    _assert_same(metrics._stable_key_order(key, 2**62), np.argsort(key, kind="stable"))
    _assert_same(metrics._stable_key_order(key, 5), np.argsort(key, kind="stable"))


def test_folded_pairs_and_dihedral_angles_match_fancy_indexing(joins):
    for _, res in joins.values():
        V0, F = res.rest_guest.V, res.guest.F
        # a deformation that folds some pairs: every other vertex pushed along z
        V1 = res.guest.V + np.where(np.arange(len(V0)) % 2, 3.0, -3.0)[:, None] * [0, 0, 1]
        pairs, edges = _ref_adjacent_face_pairs(F)
        limit = np.cos(np.radians(150.0))
        n0, _ = _ref_face_normals_areas(V0, F)
        n1, _ = _ref_face_normals_areas(V1, F)
        c0 = np.einsum("ij,ij->i", n0[pairs[:, 0]], n0[pairs[:, 1]])
        c1 = np.einsum("ij,ij->i", n1[pairs[:, 0]], n1[pairs[:, 1]])
        expected = pairs[(c1 < limit) & (c0 >= limit)]
        assert len(expected)  # the push folds pairs, so the comparison means something
        _assert_same(metrics.folded_pairs(V0, V1, F), expected)
        got_edges, angles = metrics.edge_dihedral_angles(V1, F)
        cos = np.einsum("ij,ij->i", n1[pairs[:, 0]], n1[pairs[:, 1]])
        _assert_same(got_edges, edges)
        _assert_same(angles, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


# -- seam frames on the faces at the curve ----------------------------------------------------


def test_curve_incidence_is_the_sparse_row_selection():
    """The incidence built directly; faces repeating a vertex are left to scipy's own row
    selection, so their frames are compared with the plain computation instead
    (test_seam_frames_match_frames_over_all_faces)."""
    rng = np.random.default_rng(3)
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    for trial in range(60):
        if trial % 2:
            F, n = s.guest.F[rng.random(s.guest.n_faces) < 0.5], s.guest.n_vertices
        else:  # small random complexes, faces sharing vertices in every way
            n = 12
            F = np.array([rng.choice(n, 3, replace=False) for _ in range(rng.integers(1, 30))])
        curve = rng.integers(0, n, size=rng.integers(1, 40))  # repeated curve vertices too
        got = frames._curve_incidence(F, curve, n)
        ref = frames.vertex_face_matrix(F, n)[curve].tocsr()
        assert isinstance(got, sp.csr_matrix) and got.shape == ref.shape
        for name in ("indptr", "indices", "data"):
            _assert_same(getattr(got, name), getattr(ref, name))


def _with_faces_repeating_a_vertex(V, F, curve):
    """``F`` with a face at each of three curve vertices that repeats that vertex, and one
    that is a single point: their areas are zero and their incidence above 1."""
    a, b, c = (int(v) for v in curve[[0, len(curve) // 3, len(curve) // 2]])
    far = int(np.argmax(np.linalg.norm(V - V[a], axis=1)))
    extra = np.array([[a, a, far], [far, b, b], [c, far, c], [a, a, a]])
    return np.vstack([F[: len(F) // 2], extra, F[len(F) // 2 :]])


def test_seam_frames_match_frames_over_all_faces(joins):
    for _, res in joins.values():
        sm = res.seams[0]
        cases = [
            (res.host.V, res.host.F, sm.host_curve, sm.closed, {}),
            (res.host.V, res.host.F, sm.host_curve, sm.closed, {"radius": 2.0}),
            (
                res.guest.V,
                res.guest.F,
                sm.guest_at_host,
                sm.closed,
                {"curve_points": res.host.V[sm.host_curve]},
            ),
        ]
        cases += [
            (V, _with_faces_repeating_a_vertex(V, F, curve), curve, closed, kw)
            for V, F, curve, closed, kw in cases
        ]
        for V, F, curve, closed, kw in cases:
            got = frames.seam_frames(V, F, curve, closed, **kw)
            ref = _ref_seam_frames(V, F, curve, closed, **kw)
            for name in ("normal", "tangent", "inward"):
                _assert_same(getattr(got, name), getattr(ref, name))


def test_crease_and_host_dihedral_angles_match_the_plain_computation(joins):
    for s, res in joins.values():
        sm = res.seams[0]
        host = _ref_seam_frames(res.host.V, res.host.F, sm.host_curve, sm.closed)
        guest = _ref_seam_frames(
            res.guest.V,
            res.guest.F,
            sm.guest_at_host,
            sm.closed,
            curve_points=res.host.V[sm.host_curve],
        )
        cos = np.einsum("ij,ij->i", guest.inward, -host.inward)
        crease = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        # the one-ring crease the report keeps beside the band measure
        _assert_same(res.metrics["crease_onering_deg"]["max"], float(crease.max()))
        for _ in range(2):  # computed, then read from the host's cache
            _assert_same(
                metrics.crease_angles(
                    SeamGeometry(
                        res.host.V,
                        res.host.F,
                        sm.host_curve,
                        res.guest.V,
                        res.guest.F,
                        sm.guest_at_host,
                        sm.closed,
                    )
                ),
                crease,
            )
        F = s.host.F
        band = F[_ref_ring_band(F, s.host_curve, metrics.HOST_DIHEDRAL_RINGS)]
        pairs, _ = _ref_adjacent_face_pairs(band)
        N, _ = _ref_face_normals_areas(s.host.V, band)
        dih = np.degrees(
            np.arccos(np.clip(np.einsum("ij,ij->i", N[pairs[:, 0]], N[pairs[:, 1]]), -1.0, 1.0))
        )
        for _ in range(2):
            _assert_same(metrics.host_dihedral_angles(s.host.V, s.host.F, s.host_curve), dih)
        assert res.metrics["host_dihedral_deg"]["max"] == float(dih.max())
        assert res.metrics["crease_onering_deg"]["max"] == float(crease.max())


# -- the host's values, kept on the solver ---------------------------------------------------


def test_host_values_follow_the_arrays_and_are_kept_on_the_solver():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
    V, F, curve = s.host.V.copy(), s.host.F.copy(), s.host_curve  # writeable arrays
    first = metrics.host_dihedral_angles(V, F, curve)
    # a plain function of the arrays: moved in place, the values follow the new positions
    V *= np.array([1.0, 1.0, 3.0])
    assert not np.array_equal(metrics.host_dihedral_angles(V, F, curve), first)
    # a solver makes its rigid host's values once and reuses them on every solve
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    a = solver.solve()
    kept = dict(solver.host_values.made)
    assert {key[0] for key in kept} == {"band_fit", "inward", "dihedral", "distance"}
    b = solver.solve()
    assert all(solver.host_values.made[key] is value for key, value in kept.items())
    # and they are what the plain functions give
    plain = metrics.host_dihedral_angles(s.host.V, s.host.F, s.host_curve)
    assert b.metrics["host_dihedral_deg"]["max"] == float(plain.max())
    assert a.metrics["crease_onering_deg"] == b.metrics["crease_onering_deg"]


# -- point to polyline distances --------------------------------------------------------------


@pytest.mark.parametrize("closed", [True, False])
def test_pruned_polyline_distances_equal_all_pairs(closed):
    rng = np.random.default_rng(5 + closed)
    for trial in range(12):
        k = int(rng.integers(60, 400))
        t = np.linspace(0.0, 2 * np.pi, k, endpoint=False)
        C = np.column_stack([np.cos(t), np.sin(t), 0.1 * np.sin(5 * t)]) * 10.0 ** rng.uniform(
            -3, 3
        )
        C += rng.normal(scale=1e-3, size=C.shape) * np.abs(C).max()
        if trial % 3 == 0:
            C[5] = C[4]  # a zero-length segment
            C[40:60] *= 1.5  # segments of very different lengths
        size = np.abs(C).max()
        near = C[rng.integers(0, k, 150)] + rng.normal(scale=1e-2 * size, size=(150, 3))
        far = rng.normal(scale=3 * size, size=(40, 3))  # far from the curve: many candidates
        on = C[rng.integers(0, k, 30)]  # exactly on vertices: distance 0
        P = np.vstack([near, far, on])
        assert len(P) * (k if closed else k - 1) > metrics._DENSE_PAIRS  # the pruned path
        _assert_same(
            metrics.point_polyline_distance(P, C, closed),
            _ref_point_polyline_distance(P, C, closed),
        )


def test_seam_gap_matches_all_pairs(joins):
    for _, res in joins.values():
        for sm in res.seams:
            P, C = res.guest.V[sm.seam], res.host.V[sm.host_curve]
            d = _ref_point_polyline_distance(P, C, sm.closed)
            gap = metrics.seam_gap(P, metrics.PolylineDistance(C, sm.closed))
            assert gap["max"] == float(d.max()) and gap["mean"] == float(d.mean())
            assert res.metrics["seams"][0]["seam_gap"] == gap


# -- weld: manifold checks and seam orientation -----------------------------------------------


def _libigl_checks(F):
    ids, local = np.unique(F, return_inverse=True)
    local = local.reshape(F.shape)
    return (
        bool(igl.is_edge_manifold(local)[0]),
        np.asarray(igl.is_vertex_manifold(local), dtype=bool).reshape(-1),
        local,
        len(ids),
    )


def test_topology_manifold_checks_match_libigl():
    rng = np.random.default_rng(6)
    G = phantoms.paper_sample("partial_patch", "equal", resolution=0.4).guest.F
    seen = set()
    for trial in range(240):
        kind = trial % 4
        if kind == 0:  # subsets: holes, bow-tie vertices
            F = G[rng.random(len(G)) < rng.uniform(0.2, 1.0)]
        elif kind == 1:  # repeated faces, either way round: edges with 3 or 4 faces
            extra = G[rng.integers(0, len(G), 3)]
            F = np.vstack([G, extra if trial % 8 else extra[:, ::-1]])
        elif kind == 2:  # tiny random complexes
            F = rng.integers(0, 8, size=(rng.integers(1, 12), 3))
            F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
            if not len(F):
                continue
        else:  # two copies glued at a few vertices
            H = G + G.max() + 1
            glue = rng.integers(0, G.max() + 1, 3)
            H = np.where(np.isin(H - G.max() - 1, glue), H - G.max() - 1, H)
            F = np.vstack([G, H])
        edge_ok, vertex_ok, local, n = _libigl_checks(F)
        got = (bool((topology.edges(local, n)[2] <= 2).all()), topology.vertex_manifold(local, n))
        assert got[0] == edge_ok
        _assert_same(got[1], vertex_ok)
        seen.add((edge_ok, bool(vertex_ok.all())))
    assert len(seen) == 4  # every combination of outcomes was exercised


def test_seam_orientation_counts_only_need_the_seam_faces(joins):
    for _, res in joins.values():
        w = res.merged
        F, n = w.mesh.F, w.mesh.n_vertices
        keys_all = weld_mod._directed_keys(F, n)
        keys_seam = weld_mod._directed_keys(F[metrics.ring_band(F, w.seam, 1)], n)
        for mseam, sm in zip(w.seams, res.seams):
            u = mseam if sm.closed else mseam[:-1]
            v = np.roll(mseam, -1) if sm.closed else mseam[1:]
            for a, b in ((u, v), (v, u)):
                _assert_same(
                    weld_mod._directed_count(keys_seam, a, b, n),
                    weld_mod._directed_count(keys_all, a, b, n),
                )


# -- self-intersections -----------------------------------------------------------------------


def _check_self_intersections(V, F, faces=None):
    """Fast pairs equal CGAL's on all faces, and no face CGAL reports is set aside."""
    ref = _cgal_pairs(V, F, faces)
    _assert_same(metrics.self_intersections(V, F, faces), ref)
    sel = np.arange(len(F)) if faces is None else np.flatnonzero(faces)
    if sel.size >= 2:
        sub = np.ascontiguousarray(F[sel])
        apart = metrics._apart(np.ascontiguousarray(np.take(V, sub, axis=0)), sub)
        reported = np.isin(sel, ref.reshape(-1))
        assert not (apart & reported).any()
    return ref


def test_self_intersections_of_random_soups():
    rng = np.random.default_rng(7)
    found = 0
    for _ in range(40):
        scale = 10.0 ** rng.uniform(-6, 6)
        V, F = _random_soup(rng, int(rng.integers(20, 120)), int(rng.integers(10, 80)), scale)
        V += rng.normal(size=3) * 1e3 * scale  # far from the origin: rounding matters
        found += len(_check_self_intersections(V, F))
    assert found > 100


def test_self_intersections_of_exact_touching_configurations():
    """Integer coordinates: vertices on faces, edges through edges, coplanar overlaps."""
    rng = np.random.default_rng(8)
    found = 0
    for trial in range(60):
        V = rng.integers(-3, 4, size=(40, 3)).astype(np.float64)
        if trial % 2:
            V[:, 2] = 0.0  # all coplanar: only CGAL's coplanar tests decide
        if trial % 3 == 0:
            V[20:] = V[:20]  # the same points under other indices
        F = np.array([rng.choice(40, 3, replace=False) for _ in range(50)])
        found += len(_check_self_intersections(V, F))
    # a flat grid, a face folded exactly onto its neighbour, and a duplicated face
    grid = phantoms.paper_sample("open_strip", "equal").host
    V, F = grid.V.copy(), grid.F.copy()
    pairs, _ = _ref_adjacent_face_pairs(F)
    a, b = pairs[len(pairs) // 2]
    moved = np.setdiff1d(F[a], F[b])[0]
    opposite = np.setdiff1d(F[b], F[a])[0]
    V[moved] = 0.5 * (V[moved] + V[opposite]) * 0 + V[opposite]  # onto the neighbour's corner
    F = np.vstack([F, F[3]])
    found += len(_check_self_intersections(V, F))
    assert found > 50


def _flat_grid(n: int, offset=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid of unit squares in the plane z = 0, two triangles per square."""
    x = np.arange(n, dtype=np.float64)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(n * n)]) + np.asarray(offset)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return V, F


def test_self_intersections_of_touching_grids():
    """Grids meeting exactly: overlapping in their plane, crossing, touching along a line."""
    V1, F1 = _flat_grid(8)
    found = 0
    for offset, turn in (
        ((0.5, 0.5, 0.0), False),  # coplanar, half a square over: every face overlaps
        ((0.0, 0.0, 0.0), False),  # the same points under other indices
        ((20.0, 0.0, 0.0), False),  # apart
        ((0.0, 3.0, 0.0), True),  # upright, its lower edge along a grid line: touching
        ((0.0, 3.5, -2.0), True),  # upright, through the middle of a row of squares
    ):
        V2, F2 = _flat_grid(6, (0.0, 0.0, 0.0))
        if turn:
            V2 = V2[:, [0, 2, 1]]  # into the plane y = 0
        V2 = V2 + np.asarray(offset)
        V = np.vstack([V1, V2])
        F = np.vstack([F1, F2 + len(V1)])
        found += len(_check_self_intersections(V, F))
    assert found > 100


def test_self_intersections_at_rounding_level():
    """Grids and a tube with vertices moved by 1e-17 to 1e-9 of their size."""
    rng = np.random.default_rng(11)
    strip = phantoms.paper_sample("open_strip", "equal").host
    tube = phantoms.paper_sample("end_to_end", "equal", resolution=0.4).host
    V0, F0 = _flat_grid(12)
    kept = 0
    for trial in range(24):
        mesh = (
            (strip.V, strip.F)
            if trial % 3 == 0
            else (tube.V, tube.F)
            if trial % 3 == 1
            else (V0, F0)
        )
        V, F = mesh[0].copy(), mesh[1]
        size = float(np.abs(V).max())
        moved = rng.random(len(V)) < 0.3
        V[moved] += rng.normal(size=(moved.sum(), 3)) * size * 10.0 ** rng.uniform(-17, -9)
        # and a few vertices pushed exactly onto a neighbour's neighbour
        for _ in range(3):
            f = rng.integers(0, len(F))
            V[F[f, 0]] = V[F[f, 1]] + (V[F[f, 2]] - V[F[f, 1]]) * 0.5
        _check_self_intersections(V, F)
        sub = np.ascontiguousarray(F)
        kept += int((~metrics._apart(np.ascontiguousarray(np.take(V, sub, axis=0)), sub)).sum())
    assert kept  # the sign tests met cases they could not decide


def test_self_intersections_of_real_meshes():
    pytest.importorskip("pymeshlab")
    from .cuts import sample_mesh_dir

    rng = np.random.default_rng(9)
    meshes = 0
    for path in sorted(sample_mesh_dir().rglob("*")):
        if path.suffix.lower() not in {".obj", ".ply", ".off", ".stl"}:
            continue
        try:
            mesh = igljoin.read_mesh(path)
        except igljoin.MeshError:
            continue
        if mesh.n_faces > 30_000:
            continue
        V, F = mesh.V, mesh.F
        _check_self_intersections(V, F)
        # a crumpled copy: vertices shaken by about an edge length
        edge = float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
        _check_self_intersections(V + rng.normal(scale=edge, size=V.shape), F)
        meshes += 1
    assert meshes >= 3


def test_self_intersections_of_welded_joins(joins):
    for _, res in joins.values():
        w = res.merged
        band = metrics.ring_band(w.mesh.F, w.seam, metrics.SELF_INTERSECTION_RINGS)
        _check_self_intersections(w.mesh.V, w.mesh.F, band)
        assert res.metrics["self_intersections"]["pairs"] == len(
            _cgal_pairs(w.mesh.V, w.mesh.F, band)
        )
    # the bypass graft on openings without a hood crosses itself near its seams, and a
    # guest pushed through its host
    g = phantoms.bypass_graft_sample(resolution=0.6, hood=0.0)
    res = igljoin.join(g.hosts, g.guest, seams=g.seams)
    w = res.merged
    band = metrics.ring_band(w.mesh.F, w.seam, metrics.SELF_INTERSECTION_RINGS)
    assert len(_check_self_intersections(w.mesh.V, w.mesh.F, band))
    s, res = joins["partial_patch", "equal"]
    X = res.guest.V.copy()
    inner = np.setdiff1d(
        np.unique(res.guest.F[np.isin(res.guest.F, res.seam).any(axis=1)]), res.seam
    )
    X[inner] -= 2.0 * np.array([0.0, 0.0, 1.0]) * np.sign(np.mean(res.guest.V[:, 2]) + 1e-9)
    pushed = dataclasses.replace(res, guest=Mesh(X, res.guest.F, res.guest.vertex_attributes))
    pw = pushed.merged
    band = metrics.ring_band(pw.mesh.F, pw.seam, metrics.SELF_INTERSECTION_RINGS)
    assert len(_check_self_intersections(pw.mesh.V, pw.mesh.F, band))


# -- summaries and band fits ------------------------------------------------------------------


def test_summary_median_and_p95_are_numpys_to_the_bit():
    rng = np.random.default_rng(5)
    for n in [*range(1, 60), 95, 100, 101, 2435, 4774]:
        for scale in (1e-6, 1.0, 1e6):
            v = rng.normal(size=n) * scale
            if n % 2:
                v = np.round(v / scale, 1) * scale  # ties
            got = metrics.summary(np.concatenate([v, [np.nan, np.inf]]))
            assert got == {
                "mean": float(v.mean()),
                "median": float(np.median(v)),
                "p95": float(np.percentile(v, 95)),
                "min": float(v.min()),
                "max": float(v.max()),
            }


def _ref_columns(u, v, used):
    uu = u * u
    X = np.stack([u, v, uu, u * v, v * v, uu * u, uu * uu, uu * v], axis=2)
    X[used < bandfit._FULL_MIN, :, 5:] = 0.0
    X[used < bandfit._QUADRATIC_MIN, :, 2:] = 0.0
    return X


def _ref_normal_equations(X, w):
    XtW = np.einsum("kmi,km->kim", X, w)
    return XtW, np.einsum("kim,kmj->kij", XtW, X)


@pytest.mark.parametrize("key", PAPER)
def test_compiled_band_fit_columns_and_sums_are_the_einsums(joins, key, monkeypatch):
    s, res = joins[key]
    c, sm = res.correspondence, res.seams[0]
    band = res.metrics["crease_deg"]["band"]
    cases = [(s.host.V, s.host.F, sm.host_curve), (c.V, c.F, sm.seam), (c.V, c.F, sm.guest_at_host)]
    fast = [bandfit.band_fit(V, F, curve, sm.closed, band) for V, F, curve in cases]
    monkeypatch.setattr(bandfit, "_columns", _ref_columns)
    monkeypatch.setattr(bandfit, "_normal_equations", _ref_normal_equations)
    # the reference solves over every column (the fast fit leaves out weightless ones where
    # they are many, as on the end-to-end samples)
    monkeypatch.setattr(bandfit, "_COMPACT_WIDTH", -1.0)
    for (V, F, curve), a in zip(cases, fast):
        b = bandfit.band_fit(V, F, curve, sm.closed, band)
        _assert_same(a.counts, b.counts)
        _assert_same(a.slope_error, b.slope_error)
        _assert_same(a.frames.inward, b.frames.inward)
        _assert_same(a.frames.normal, b.frames.normal)
        assert (a.weights != b.weights).nnz == 0
        _assert_same(a.weights.indices, b.weights.indices)


# -- what a solver keeps between solves: the same measures from fewer operations -------------


def _seam_geometry(res, i=0):
    sm = res.seams[i]
    return SeamGeometry(
        res.host.V, res.host.F, sm.host_curve, res.guest.V, res.guest.F, sm.guest_at_host, sm.closed
    )


def test_kept_curve_faces_give_the_frames_at_other_positions(joins):
    rng = np.random.default_rng(11)
    for _, res in joins.values():
        seam = _seam_geometry(res)
        sm = res.seams[0]
        kept = metrics.guest_curve_faces(seam)
        host = frames.curve_faces(
            res.host.F, sm.host_curve, len(res.host.V), seam.host_points, sm.closed, radius=2.0
        )
        # made once, used at other positions: the plain computation at those positions
        host_inward = _ref_seam_frames(res.host.V, res.host.F, sm.host_curve, sm.closed).inward
        for V in (res.guest.V, res.rest_guest.V, res.guest.V + rng.normal(size=res.guest.V.shape)):
            moved = seam.with_guest(V)
            ref = _ref_seam_frames(
                V, seam.Fg, seam.guest_at_host, seam.closed, curve_points=seam.host_points
            )
            got = frames.curve_frames(V, kept)
            for name in ("normal", "tangent", "inward"):
                _assert_same(getattr(got, name), getattr(ref, name))
            cos = np.einsum("ij,ij->i", ref.inward, -host_inward)
            _assert_same(
                metrics.crease_angles(moved, guest_faces=kept),
                np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))),
            )
        for V in (res.host.V, res.host.V + rng.normal(scale=0.1, size=res.host.V.shape)):
            got = frames.curve_frames(V, host)
            ref = _ref_seam_frames(
                V, res.host.F, sm.host_curve, sm.closed, radius=2.0, curve_points=seam.host_points
            )
            for name in ("normal", "tangent", "inward"):
                _assert_same(getattr(got, name), getattr(ref, name))


def test_kept_curve_faces_of_faces_repeating_a_vertex():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 0, 3]])  # the last face repeats vertex 0
    seam = SeamGeometry(V, F[:2], [0, 1], V, F, [0, 1], False)
    kept = metrics.guest_curve_faces(seam)
    assert kept.incidence[0, 2] == 2.0  # vertex 0 twice in the last face
    host_inward = _ref_seam_frames(V, F[:2], [0, 1], False).inward
    lifted = V + np.array([0.0, 0.0, 0.3]) * V[:, [1]]  # the faces no longer flat
    for X in (V, lifted):
        ref = _ref_seam_frames(X, F, [0, 1], False, curve_points=V[[0, 1]])
        _assert_same(frames.curve_frames(X, kept).inward, ref.inward)
        cos = np.einsum("ij,ij->i", ref.inward, -host_inward)
        _assert_same(
            metrics.crease_angles(seam.with_guest(X), guest_faces=kept),
            np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))),
        )


@pytest.mark.parametrize("closed", [True, False])
def test_a_kept_polyline_distance_measures_as_the_function(closed):
    rng = np.random.default_rng(21 + closed)
    t = np.linspace(0.0, 2 * np.pi, 90, endpoint=False)
    C = np.column_stack([np.cos(t), np.sin(t), 0.1 * np.sin(3 * t)]) * 20.0
    kept = metrics.PolylineDistance(C, closed)
    for count in (5, 40, 300):  # the all-pairs path, then the pruned one, measured again
        P = C[rng.integers(0, len(C), count)] + rng.normal(scale=0.5, size=(count, 3))
        want = _ref_point_polyline_distance(P, C, closed)
        _assert_same(kept(P), want)
        _assert_same(metrics.point_polyline_distance(P, C, closed), want)
        made = metrics.PolylineDistance(C, closed)
        assert metrics.seam_gap(P, kept) == metrics.seam_gap(P, made)
    assert kept.mean_segment == igljoin.polyline.mean_segment(C, closed)


def test_kept_incidence_and_rigid_reference_give_the_plain_maps(joins):
    for _, res in joins.values():
        V0, V1, F = res.rest_guest.V, res.guest.V, res.guest.F
        E = np.asarray(igl.edges(F), dtype=np.int64)
        n = len(V0)
        strain = metrics.edge_strain(V0, V1, E)
        incidence = metrics.vertex_incidence(E, n)
        _assert_same(
            metrics.vertex_strain(E, strain, n, incidence=incidence),
            metrics.vertex_strain(E, strain, n),
        )
        # a strain that is not finite everywhere leaves the kept incidence aside
        broken = strain.copy()
        broken[::7] = np.nan
        got = metrics.vertex_strain(E, broken, n, incidence=incidence)
        _assert_same(got, metrics.vertex_strain(E, broken, n))
        assert not np.array_equal(got, metrics.vertex_strain(E, strain, n), equal_nan=True)
        rest = correspond.rigid_reference(np.asarray(V0, dtype=np.float64))
        # a mirror image: the best fit is a proper rotation, not the reflection
        for W in (V1, V1[::-1].copy(), V0, V1 * np.array([1.0, 1.0, -1.0])):
            R, t = _ref_rigid_fit(V0, W)
            assert np.linalg.det(R) > 0  # proper, the mirror image included
            for got in (correspond.rigid_fit_to(rest, W), correspond.rigid_fit(V0, W)):
                _assert_same(got[0], R)
                _assert_same(got[1], t)
            # the distances to the reference fit's motion, with the kept rest side and without
            # (a tolerance of 1e-12 of the guest's size: the row norms sum in another order)
            plain = np.linalg.norm(W - (V0 @ R.T + t), axis=1)
            for got in (
                metrics.nonrigid_displacement(V0, W, rest=rest),
                metrics.nonrigid_displacement(V0, W),
            ):
                assert np.allclose(got, plain, rtol=0, atol=1e-12 * np.ptp(V0))


def test_folded_pairs_from_given_normals(joins):
    for _, res in joins.values():
        V0, F = res.rest_guest.V, res.guest.F
        V1 = res.guest.V + np.where(np.arange(len(V0)) % 2, 3.0, -3.0)[:, None] * [0, 0, 1]
        normals, _ = frames.face_normals_areas(V1, F)
        got = metrics.folded_pairs(V0, V1, F, rest=metrics.fold_reference(V0, F), normals=normals)
        want = metrics.folded_pairs(V0, V1, F)
        assert len(want)  # the push folds pairs
        _assert_same(got, want)


def test_coordinate_major_arrays_measure_as_the_arrays(joins):
    """The measures copy their inputs coordinate-major; given such arrays they copy nothing
    and give the same values."""
    for _, res in joins.values():
        V1, F = res.guest.V, res.guest.F
        E = np.asarray(igl.edges(F), dtype=np.int64)
        Vc, Fc, Ec = (np.ascontiguousarray(A.T).T for A in (V1, F, E))
        for got, want in zip(frames.face_normals_areas(Vc, Fc), frames.face_normals_areas(V1, F)):
            _assert_same(got, want)
        _assert_same(metrics.edge_lengths(Vc, Ec), metrics.edge_lengths(V1, E))


def test_a_joins_meshes_are_what_the_checked_constructor_makes(joins):
    for _, res in joins.values():
        for mesh in (res.guest, res.rest_guest):
            checked = Mesh(
                mesh.V, mesh.F, mesh.vertex_attributes, mesh.face_attributes, name=mesh.name
            )
            for name in ("V", "F"):
                _assert_same(getattr(mesh, name), getattr(checked, name))
                assert not getattr(mesh, name).flags.writeable
                assert getattr(mesh, name).flags.c_contiguous
            for kind in ("vertex_attributes", "face_attributes"):
                got, want = getattr(mesh, kind), getattr(checked, kind)
                assert list(got) == list(want)
                for key in got:
                    _assert_same(got[key], want[key])
                    assert not got[key].flags.writeable
        # the deformed guest owns its positions; the area ratio is the result's own, writable
        assert res.guest.V.base is None and res.area_ratio.flags.writeable
        assert not np.shares_memory(res.area_ratio, res.guest.face_attributes["area_ratio"])


def test_results_share_the_rest_arrays_but_cannot_write_them():
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    a, b = solver.solve(), solver.solve()
    assert a.rest_guest is not b.rest_guest and a.guest is not b.guest
    assert np.shares_memory(a.rest_guest.V, b.rest_guest.V)
    assert np.shares_memory(a.guest.F, b.rest_guest.F)
    for array in (a.rest_guest.V, a.rest_guest.F, a.guest.F):
        with pytest.raises(ValueError):
            array.flags.writeable = True  # a view of a read-only copy: no way to write
    _assert_same(a.rest_guest.V, solver.corr.V)
    _assert_same(a.guest.F, solver.corr.F)


def test_a_solve_gone_non_finite_is_refused_by_the_mesh_checks():
    from igljoin.measure_join import _deformed_guest

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    X = s.guest.V.copy()
    X[3] = np.nan
    with pytest.raises(igljoin.MeshError, match="deformed guest: 1 vertices have NaN"):
        _deformed_guest(X, s.guest.F, {}, {})
