"""Welded output and saved results (issue: welded output and the join-quality report).

Every welded mesh is checked with libigl and with pymeshlab, not with
igljoin's own checks.
"""

from __future__ import annotations

import dataclasses
import json

import igl
import numpy as np
import pytest

import igljoin
from igljoin import phantoms
from igljoin.weld import GUEST, HOST, Welded, weld

from .cuts import cut_piece, rigid_motion, sample_mesh_dir

pymeshlab = pytest.importorskip("pymeshlab")  # independent topology checks, real meshes

PAPER = [f"{sc}/{ln}" for sc in ("end_to_end", "partial_patch") for ln in phantoms.LENGTH_RATIOS]
CASES = [*PAPER, "open_strip/equal", "end_to_end/coarse", "partial_patch/coarse", "bunny"]


@dataclasses.dataclass
class Case:
    host: igljoin.Mesh
    res: igljoin.JoinResult
    original: igljoin.Mesh | None = None  # the uncut mesh, for the bunny


def _bunny_case() -> Case:
    """The first clean cut of a seeded sequence on the real bunny, moved and joined back."""
    bunny = igljoin.read_mesh(sample_mesh_dir() / "bunny.obj")
    rng = np.random.default_rng(1)
    size = float(np.linalg.norm(np.ptp(bunny.V, axis=0)))
    while True:
        cut = cut_piece(bunny, int(rng.integers(bunny.n_vertices)), size * rng.uniform(0.05, 0.2))
        if cut is not None:
            break
    R, t = rigid_motion(0, cut.diameter)
    moved = igljoin.Mesh(cut.piece.V @ R.T + t, cut.piece.F)
    return Case(cut.host, igljoin.join(cut.host, moved, cut.host_curve, None), bunny)


class _Cases(dict):
    """Joins built on first use and shared by the tests of this module."""

    def __missing__(self, name: str) -> Case:
        if name == "bunny":
            case = _bunny_case()
        else:
            scenario, length = name.split("/")
            kw = {"guest_resolution": 0.2} if length == "coarse" else {}
            s = phantoms.paper_sample(scenario, "equal" if length == "coarse" else length, **kw)
            case = Case(s.host, igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve))
        self[name] = case
        return case


@pytest.fixture(scope="module")
def cases() -> _Cases:
    return _Cases()


def _canonical(F: np.ndarray) -> np.ndarray:
    """Faces rotated so that their smallest vertex comes first (orientation kept)."""
    r = np.argmin(F, axis=1)
    idx = (r[:, None] + np.arange(3)[None, :]) % 3
    return np.take_along_axis(F, idx, axis=1)


def _unchanged_per_component(F: np.ndarray, G: np.ndarray, comp: np.ndarray) -> bool:
    """Re-orienting ``F`` into ``G`` changed nothing, or flipped whole components only."""
    same = (_canonical(F) == _canonical(G)).all(axis=1)
    return all(same[comp == c].all() or (~same[comp == c]).all() for c in np.unique(comp))


def _measures(V: np.ndarray, F: np.ndarray) -> dict:
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    return ms.get_topological_measures()


def _host_edge(res: igljoin.JoinResult) -> float:
    P = res.host.V[res.host_curve]
    seg = np.roll(P, -1, axis=0) - P if res.closed else np.diff(P, axis=0)
    return float(np.linalg.norm(seg, axis=1).mean())


# -- topology, checked by libigl and by pymeshlab ---------------------------------------------


@pytest.mark.parametrize("name", CASES)
def test_libigl_finds_an_oriented_manifold(cases, name):
    res = cases[name].res
    V, F = res.merged.mesh.V, res.merged.mesh.F
    assert igl.is_edge_manifold(F)[0]
    assert np.asarray(igl.is_vertex_manifold(F)).all()
    FF, comp = igl.bfs_orient(F)
    assert _unchanged_per_component(F, FF, comp)
    # every face has positive area
    assert igl.doublearea(V, F).min() > 0.0


@pytest.mark.parametrize("name", CASES)
def test_pymeshlab_finds_an_oriented_manifold(cases, name):
    case = cases[name]
    res = case.res
    w = res.merged
    got = _measures(w.mesh.V, w.mesh.F)
    assert got["non_two_manifold_edges"] == 0
    assert got["non_two_manifold_vertices"] == 0
    assert got["is_mesh_two_manifold"]
    host = _measures(case.host.V, case.host.F)
    guest = _measures(res.guest.V, res.guest.F)
    assert got["connected_components_number"] == (
        host["connected_components_number"] + guest["connected_components_number"] - 1
    )
    # the seam's edges stop being boundary: k host curve edges split into s, and s guest edges
    # (one fewer of each on an open seam)
    k, s = len(res.host_curve), len(res.seam)
    open_ = 0 if res.closed else 2
    expected = host["boundary_edges"] + guest["boundary_edges"] - k - s + open_
    assert got["boundary_edges"] == expected
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=w.mesh.V, face_matrix=w.mesh.F.astype(np.int32)))
    ms.meshing_re_orient_faces_coherently()
    G = ms.current_mesh().face_matrix().astype(np.int64)
    comp = igl.facet_components(w.mesh.F)[1]
    assert _unchanged_per_component(w.mesh.F, G, comp)


@pytest.mark.parametrize("name", CASES)
def test_counts(cases, name):
    case = cases[name]
    res, w = case.res, case.res.merged
    k, s = len(res.host_curve), len(res.seam)
    splits = s - k  # seam vertices that are not host curve vertices split a host edge
    assert w.n_splits == splits == int(np.sum(w.source[w.seam, 0] == GUEST))
    # host (with the vertices its split edges gain) + guest - the s shared seam vertices
    assert w.mesh.n_vertices == (case.host.n_vertices + splits) + res.guest.n_vertices - s
    assert w.mesh.n_faces == case.host.n_faces + splits + res.guest.n_faces
    assert (w.label == HOST).sum() == case.host.n_faces + splits
    assert int(w.seam_flag.sum()) == s
    if name == "bunny":  # cut out and welded back: the bunny's own counts and topology
        a, b = _measures(w.mesh.V, w.mesh.F), _measures(case.original.V, case.original.F)
        for key in ("vertices_number", "faces_number", "boundary_edges", "genus"):
            assert a[key] == b[key], key


@pytest.mark.parametrize("name", CASES)
def test_boundary_is_what_was_not_joined(cases, name):
    case = cases[name]
    res, w = case.res, case.res.merged
    as_source = [{tuple(p) for p in w.source[lp]} for lp in igljoin.boundary_loops(w.mesh.F)]
    host_loops = igljoin.boundary_loops(case.host.F)
    guest_loops = igljoin.boundary_loops(res.guest.F)
    host_rest = [lp for lp in host_loops if not np.isin(res.host_curve, lp).any()]
    guest_rest = [lp for lp in guest_loops if not np.isin(res.seam, lp).any()]
    expected = [{(HOST, int(v)) for v in lp} for lp in host_rest]
    expected += [{(GUEST, int(v)) for v in lp} for lp in guest_rest]
    if res.closed:
        # the joined pair of loops is gone, every other loop is left exactly
        assert sorted(map(sorted, as_source)) == sorted(map(sorted, expected))
    else:
        # the two joined loops become one; the others are left exactly
        assert len(as_source) == len(host_loops) + len(guest_loops) - 1
        assert all(loop in as_source for loop in expected)


@pytest.mark.parametrize("name", CASES)
def test_source_map_and_host_unchanged(cases, name):
    case = cases[name]
    res, w = case.res, case.res.merged
    V, src = w.mesh.V, w.source
    host_v, guest_v = src[:, 0] == HOST, src[:, 0] == GUEST
    np.testing.assert_array_equal(V[host_v], case.host.V[src[host_v, 1]])
    # adopted seam vertices sit on the host edge; the guest held them there up to rounding
    # (1e-9 of a seam edge, the seam bound of test_join)
    dist = np.linalg.norm(V[guest_v] - res.guest.V[src[guest_v, 1]], axis=1)
    assert dist.max() <= 1e-9 * _host_edge(res)
    # splitting moved nothing: the host faces cover the host's area (1e-12: summation order)
    host_area = igl.doublearea(V, w.mesh.F[w.label == HOST]).sum()
    assert host_area == pytest.approx(igl.doublearea(case.host.V, case.host.F).sum(), rel=1e-12)
    # attributes: host faces 1.0, guest faces the join's area ratio
    ratio = w.mesh.face_attributes["area_ratio"]
    assert (ratio[w.label == HOST] == 1.0).all()
    np.testing.assert_array_equal(ratio[w.label == GUEST], res.area_ratio)
    disp = w.mesh.vertex_attributes["displacement"]
    np.testing.assert_array_equal(
        disp[guest_v], res.guest.vertex_attributes["displacement"][src[guest_v, 1]]
    )
    assert (disp[host_v & ~w.seam_flag] == 0.0).all()


def test_closed_curves_never_flip_the_guest(cases):
    for name in CASES:
        if cases[name].res.closed:
            assert not cases[name].res.merged.flipped_guest, name


def test_two_tubes_weld_into_one_tube(cases):
    case = cases["end_to_end/equal"]
    res, w = case.res, case.res.merged
    loops = igljoin.boundary_loops(w.mesh.F)
    assert len(loops) == 2
    far_host = [lp for lp in igljoin.boundary_loops(case.host.F) if 0 not in lp]
    far_guest = [lp for lp in igljoin.boundary_loops(res.guest.F) if res.seam[0] not in lp]
    ends = {frozenset(map(tuple, w.source[lp])) for lp in loops}
    assert ends == {
        frozenset((HOST, int(v)) for v in far_host[0]),
        frozenset((GUEST, int(v)) for v in far_guest[0]),
    }
    m = _measures(w.mesh.V, w.mesh.F)
    # one piece, genus 0, two holes: a tube (Euler characteristic 0)
    assert m["connected_components_number"] == 1 and m["genus"] == 0 and m["number_holes"] == 2
    assert m["vertices_number"] - m["edges_number"] + m["faces_number"] == 0


def test_open_curve_with_reversed_guest_is_flipped():
    s = phantoms.paper_sample("open_strip", "equal", resolution=0.5)
    plain = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    reversed_guest = igljoin.Mesh(s.guest.V, s.guest.F[:, ::-1])
    res = igljoin.join(s.host, reversed_guest, s.host_curve, s.guest_curve)
    assert res.merged.flipped_guest != plain.merged.flipped_guest
    for r in (plain, res):
        F = r.merged.mesh.F
        FF, comp = igl.bfs_orient(F)
        assert _unchanged_per_component(F, FF, comp)
        assert r.report()["metrics"]["weld"]["flipped_guest"] == r.merged.flipped_guest


def test_merged_is_cached_and_matches_weld(cases):
    res = cases["partial_patch/equal"].res
    assert res.merged is res.merged
    again = res.weld()
    assert isinstance(again, Welded)
    np.testing.assert_array_equal(again.mesh.F, res.merged.mesh.F)
    np.testing.assert_array_equal(again.mesh.V, res.merged.mesh.V)
    # the same weld from plain arrays and the seam records; without the guest's maps
    # the welded mesh carries only its own attributes
    plain = weld(res.host.V, res.host.F, res.guest.V, res.guest.F, res.seams)
    np.testing.assert_array_equal(plain.mesh.F, res.merged.mesh.F)
    np.testing.assert_array_equal(plain.mesh.V, res.merged.mesh.V)
    assert set(plain.mesh.vertex_attributes) == {"seam", "source", "source_id"}
    assert set(plain.mesh.face_attributes) == {"label", "source_face"}


# -- errors -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    """A join with host edge splits, small enough to break in several ways."""
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    return solver, solver.solve()


def _with_guest(res, V, F, extra_faces=0):
    attrs = {
        k: np.concatenate([v, np.zeros(len(V) - len(v), v.dtype)])
        for k, v in res.guest.vertex_attributes.items()
    }
    ratio = np.concatenate([res.area_ratio, np.ones(extra_faces)])
    return dataclasses.replace(res, guest=igljoin.Mesh(V, F, attrs), area_ratio=ratio)


def _seam_face(res, k=2):
    """A guest face with ``k`` seam vertices."""
    on = np.isin(res.guest.F, res.seam).sum(axis=1)
    return int(np.flatnonzero(on == k)[0])


def test_seam_off_the_host_curve_is_reported_not_raised(small, tmp_path):
    solver, res = small
    moved = solver.solve(targets=res.seam_targets + [0.0, 0.0, 0.5])
    assert moved.metrics["weld"]["ok"] is False
    assert "off the host curve" in moved.metrics["weld"]["error"]
    assert moved.metrics["self_intersections"] is None
    json.dumps(moved.report(), allow_nan=False)
    with pytest.raises(igljoin.WeldError, match="off the host curve by up to 0.5"):
        _ = moved.merged
    with pytest.raises(igljoin.WeldError, match=r"merged=False"):
        moved.save(tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written when the weld fails
    paths = moved.save(tmp_path / "out", merged=False)
    assert set(paths) == {"guest", "guest_vtu", "report"}


def test_duplicated_seam_face_is_non_manifold(small):
    res = small[1]
    f = _seam_face(res)
    broken = _with_guest(res, res.guest.V, np.vstack([res.guest.F, res.guest.F[f]]), 1)
    # the copy adds a third face to each of the face's three edges, and to no other edge
    with pytest.raises(igljoin.WeldError, match=r"weld: 3 edges have more than two faces") as e:
        broken.weld()
    named = json.loads(str(e.value).split("seam vertices ")[1].split(" (")[0])
    # exactly the face's two seam vertices are named (merged ids follow the seam order)
    merged_of = dict(zip(res.seam.tolist(), res.merged.seam.tolist()))
    expected = {merged_of[v] for v in res.guest.F[f].tolist() if v in merged_of}
    assert len(expected) == 2 and set(named) == expected


def test_dangling_triangle_at_a_seam_vertex_is_not_vertex_manifold(small):
    res = small[1]
    X, F = res.guest.V, res.guest.F
    v = int(res.seam[0])
    V2 = np.vstack([X, X[v] + [[5.0, 0.0, 0.0], [5.0, 5.0, 0.0]]])
    F2 = np.vstack([F, [[v, len(X), len(X) + 1]]])
    with pytest.raises(igljoin.WeldError, match="separate fans of faces at seam vertices"):
        _with_guest(res, V2, F2, 1).weld()


def test_inconsistent_orientation_is_named(small):
    res = small[1]
    F = res.guest.F.copy()
    f = _seam_face(res)
    F[f] = F[f, ::-1]
    with pytest.raises(igljoin.WeldError, match="same direction at seam vertices"):
        _with_guest(res, res.guest.V, F).weld()


def test_zero_area_face_is_named(small):
    res = small[1]
    X = res.guest.V.copy()
    a, b, c = res.guest.F[_seam_face(res)]
    inner = [x for x in (a, b, c) if x not in set(res.seam.tolist())][0]
    pair = [x for x in (a, b, c) if x != inner]
    X[inner] = X[pair].mean(axis=0)  # the face collapses onto its seam edge
    with pytest.raises(igljoin.WeldError, match="zero area at seam vertices"):
        _with_guest(res, X, res.guest.F).weld()


def test_weld_needs_seam_records_and_values_of_the_right_size(small):
    res = small[1]
    arrays = (res.host.V, res.host.F, res.guest.V, res.guest.F)
    with pytest.raises(igljoin.WeldError, match="seams must be a non-empty list of igljoin.weld"):
        weld(*arrays, [(res.host_curve, res.seam)])
    with pytest.raises(igljoin.WeldError, match="seams must be a non-empty list"):
        weld(*arrays, [])
    with pytest.raises(igljoin.WeldError, match=r"area_ratio has shape \(3,\); give one value"):
        weld(*arrays, res.seams, area_ratio=np.ones(3))


# -- saved files ------------------------------------------------------------------------------


def test_save_round_trip(cases, tmp_path):
    res = cases["end_to_end/shorter"].res
    folder = tmp_path / "new" / "case"  # created with its parents
    paths = res.save(folder)
    assert set(paths) == {"guest", "merged", "guest_vtu", "merged_vtu", "report"}
    assert sorted(p.name for p in folder.iterdir()) == [
        "guest.ply",
        "guest.vtu",
        "merged.ply",
        "merged.vtu",
        "report.json",
    ]
    for key, mesh in (("guest", res.guest), ("merged", res.merged.mesh)):
        back = igljoin.read_mesh(paths[key])
        # PLY stores float64 (%.17g in ASCII) and int32: exact round trip
        np.testing.assert_array_equal(back.V, mesh.V)
        np.testing.assert_array_equal(back.F, mesh.F)
        # every attribute comes back (as float64), plus MeshLab's quality copies
        vq = {"quality": mesh.vertex_attributes["displacement"]}
        fq = {"quality": mesh.face_attributes["area_ratio"]}
        for kind, extra in (("vertex_attributes", vq), ("face_attributes", fq)):
            want, got = {**getattr(mesh, kind), **extra}, getattr(back, kind)
            assert set(got) == set(want), (key, kind)
            for name, values in want.items():
                np.testing.assert_array_equal(got[name], values.astype(np.float64))
        # pymeshlab (MeshLab) opens the file: double coordinates and the quality maps, exact
        ms = pymeshlab.MeshSet()
        ms.load_new_mesh(str(paths[key]))
        m = ms.current_mesh()
        np.testing.assert_array_equal(m.vertex_matrix(), mesh.V)
        np.testing.assert_array_equal(m.face_matrix(), mesh.F)
        np.testing.assert_array_equal(m.vertex_scalar_array(), vq["quality"])
        np.testing.assert_array_equal(m.face_scalar_array(), fq["quality"])
    assert set(igljoin.read_mesh(paths["guest"]).vertex_attributes) == {
        "displacement",
        "strain",
        "seam",
        "quality",
    }
    assert set(igljoin.read_mesh(paths["merged"]).face_attributes) == {
        "label",
        "source_face",
        "area_ratio",
        "quality",
    }
    report = json.loads(paths["report"].read_text())
    assert report == json.loads(json.dumps(res.report()))
    assert report["options"]["smooth"] is True
    # saving again replaces the files (atomically; no temporary file is left behind)
    again = res.save(folder)
    assert again == paths
    assert len(list(folder.iterdir())) == 5


def test_save_into_a_file_is_refused(cases, tmp_path):
    target = tmp_path / "file.txt"
    target.write_text("x")
    with pytest.raises(NotADirectoryError, match="not a folder"):
        cases["partial_patch/equal"].res.save(target)


def test_zero_area_guest_face_far_from_the_seam_is_found(small):
    """The area check runs on every guest face, not only at the seam (the join moves them all)."""
    res = small[1]
    X = res.guest.V.copy()
    far = np.flatnonzero(~np.isin(res.guest.F, res.seam).any(axis=1))
    a, b, c = res.guest.F[far[-1]]
    X[c] = 0.5 * (X[a] + X[b])  # the face collapses onto one of its edges
    with pytest.raises(igljoin.WeldError, match="zero area"):
        _with_guest(res, X, res.guest.F).weld()
