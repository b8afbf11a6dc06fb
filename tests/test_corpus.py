"""Do no harm on real cuts: the real-mesh corpus joined back with the default options.

The corpus (``tests/cuts.py``: ``CORPUS``) cuts five of pymeshlab's sample
meshes by balls, by planes along existing edges and by planes splitting
triangles, in three places each. Every piece is joined back as it was cut
and after a rigid motion, with the default options, and must come back
(issue 14's bars). Where the uncut surface itself is creased along the cut
(the cases made so, ``creased=True``; the measure must read more than
``CREASED_DEG`` there), a smooth join has to move the piece: there the bars
are only that the crease does not rise, nothing folds and the result says
the host was creased. Which cases are creased is fixed by the corpus, not
read from the measure: a measure that read a smooth cut as creased would
otherwise exempt it from the bars.
"""

from __future__ import annotations

import numpy as np
import pytest

import igljoin

from .cuts import (
    CORPUS,
    STYLES,
    corpus_cut,
    crease_measure_name,
    plane_cut_along_edges,
    plane_cut_split,
    read_sample,
    rejoin,
    split_on_plane,
)

pytest.importorskip("pymeshlab")  # ships the real meshes

#: An uncut crease above this (degrees, largest along the seam) is a real crease
#: of the surface along the cut (issue 14: "more than about 10 degrees").
CREASED_DEG = 10.0

IDS = [case.name for case in CORPUS]


@pytest.fixture(scope="module")
def cuts():
    meshes = {name: read_sample(name) for name in sorted({c.mesh for c in CORPUS})}
    return {
        case.name: (case, meshes[case.mesh], corpus_cut(case, meshes[case.mesh])) for case in CORPUS
    }


@pytest.fixture(scope="module")
def runs(cuts):
    """Every corpus cut joined back untouched and moved (seed = its place in CORPUS)."""
    return {case.name: rejoin(cuts[case.name][2], i) for i, case in enumerate(CORPUS)}


def _band(run):
    if run.band is None:
        pytest.fail(
            "the crease bars need the band measure igljoin.crease.seam_crease "
            f"(issue 14 item 1); this igljoin has only the {crease_measure_name()} measure"
        )


# --- the corpus itself -------------------------------------------------------------


def test_corpus_spans_meshes_styles_places_and_sizes(cuts):
    meshes = {case.mesh for case, _, _ in cuts.values()}
    assert len(meshes) >= 4
    for mesh in meshes:
        for style in STYLES:
            places = [c for c, _, _ in cuts.values() if c.mesh == mesh and c.style == style]
            assert len({c.center for c in places}) >= 3, (mesh, style)
    sizes = [cut.piece.n_vertices for _, _, cut in cuts.values()]
    # the issue: pieces from under 100 to several thousand vertices
    assert min(sizes) < 100 and max(sizes) >= 3000
    assert any(c.creased and c.mesh == "airplane.obj" for c, _, _ in cuts.values())


@pytest.mark.parametrize("name", IDS)
def test_cut_is_a_disk_on_a_manifold_host(cuts, name):
    case, mesh, cut = cuts[name]
    assert len(igljoin.boundary_loops(cut.piece.F)) == 1
    # the piece's seam vertices sit on the host curve vertices
    np.testing.assert_array_equal(cut.piece.V[cut.piece_at_host], cut.host.V[cut.host_curve])
    if case.style != "split":  # faces are kept or removed whole: none lost, none twice
        assert len(cut.piece.F) + len(cut.host.F) == len(mesh.F)
    else:  # each split triangle became three
        assert (len(cut.piece.F) + len(cut.host.F) - len(mesh.F)) % 2 == 0
        assert len(cut.piece.F) + len(cut.host.F) > len(mesh.F)


@pytest.mark.parametrize("name", [c.name for c in CORPUS if c.style != "ball"])
def test_plane_bounds_most_of_a_plane_cut(cuts, name):
    case, mesh, cut = cuts[name]
    n = np.asarray(case.normal) / np.linalg.norm(case.normal)
    P = cut.host.V[cut.host_curve]
    d = np.abs((P - mesh.V[case.center]) @ n + case.offset)
    e = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    # split: new vertices lie on the plane up to rounding (1e-9 of the piece's size);
    # along edges: a seam vertex beside the plane is within half a seam edge of it
    tol = 1e-9 * cut.diameter if case.style == "split" else 0.5 * e.mean()
    # the search kept plane cuts whose plane bounds at least half the seam
    assert np.mean(d <= tol) >= 0.5


@pytest.mark.parametrize("name", [c.name for c in CORPUS if c.style == "split"])
def test_split_cut_keeps_slivers(cuts, name):
    _, _, cut = cuts[name]
    P = cut.host.V[cut.host_curve]
    e = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    # very short seam edges are what a split cut gives: under a tenth of the mean
    assert e.min() < 0.1 * e.mean()


@pytest.mark.parametrize("name", [c.name for c in CORPUS if c.style == "edges"])
def test_cut_along_edges_adds_no_vertex(cuts, name):
    _, mesh, cut = cuts[name]
    used = mesh.V[np.unique(mesh.F)]
    rows = {tuple(v) for v in used}
    assert all(tuple(v) in rows for v in cut.host.V[cut.host_curve])


# --- the cutting code on small cases ----------------------------------------------


def _two_triangles():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    return V, F


def test_split_on_plane_shares_the_new_vertex_and_keeps_area_and_orientation():
    V, F = _two_triangles()
    # the plane x = 0.3 crosses edges 0-1, 2-3 and the shared edge 1-2
    V2, F2 = split_on_plane(V, F, (0.3, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert len(F2) == 6  # each crossing triangle becomes three
    assert len(V2) == 4 + 3  # edges 0-1, 1-2 (shared by both triangles), 2-3
    np.testing.assert_allclose(V2[4:, 0], 0.3, atol=1e-15)  # on the plane up to rounding
    area = 0.5 * np.linalg.norm(
        np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]]), axis=1
    )
    # the split covers the same square exactly (float rounding only)
    assert abs(area.sum() - 1.0) < 1e-12
    z = np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]])[:, 2]
    assert (z > 0).all()  # every face keeps the input's orientation (+z)
    assert len(igljoin.boundary_loops(F2)) == 1  # one surface: no crack at the shared edge


def test_split_on_plane_keeps_a_sliver_near_a_vertex():
    V, F = _two_triangles()
    V2, F2 = split_on_plane(V, F, (1e-6, 0.0, 0.0), (1.0, 0.0, 0.0))
    P = V2[F2]
    area = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    # the plane 1e-6 from vertex 0: a triangle of area ~1e-12 is kept, not cleaned
    assert area.min() < 1e-11
    assert len(F2) == 6


def test_split_on_plane_through_a_vertex_splits_the_opposite_edge_only():
    V, F = _two_triangles()
    # the plane x + y = 1 through vertices 1 and 2: no triangle is crossed
    V2, F2 = split_on_plane(V, F, (1.0, 0.0, 0.0), (1.0, 1.0, 0.0))
    assert len(V2) == 4 and len(F2) == 2
    # the plane x = y through vertices 0 and 3 ... crosses edge 1-2 only
    V2, F2 = split_on_plane(V, F, (0.0, 0.0, 0.0), (1.0, -1.0, 0.0))
    assert len(V2) == 5 and len(F2) == 4
    np.testing.assert_allclose(V2[4], [0.5, 0.5, 0.0], atol=1e-15)


def test_plane_cuts_refuse_a_piece_that_is_not_a_disk():
    tube = igljoin.phantoms.artery_tube(radius=4.0, length=40.0, n_around=24, n_along=12)
    c = int(np.argmin(np.linalg.norm(tube.V - [4.0, 0.0, 25.0], axis=1)))
    offset = tube.V[c, 2] - 20.0  # the plane z = 20, across the tube
    for cut in (plane_cut_along_edges, plane_cut_split):
        # a ball of radius 3 keeps the piece a patch of the wall: a disk
        assert cut(tube, c, (0.0, 0.0, 1.0), offset, 3.0) is not None
        # radius 9 > the tube's width 8: the piece runs round the tube, an
        # annulus with two boundary loops
        assert cut(tube, c, (0.0, 0.0, 1.0), offset, 9.0) is None
        # radius 30 reaches the tube's open end at z = 40: no clean cut either
        assert cut(tube, c, (0.0, 0.0, 1.0), offset, 30.0) is None


def test_corpus_cut_names_a_case_that_no_longer_cuts():
    case = CORPUS[0]
    mesh = read_sample(case.mesh)
    boundary = int(igljoin.boundary_loops(mesh.F)[0][0])  # bunny10k is open
    bad = type(case)(case.mesh, "ball", boundary, case.radius)
    with pytest.raises(RuntimeError, match="no longer a clean disk cut"):
        corpus_cut(bad, mesh)


# --- issue 14's bars, default options ------------------------------------------------


SMOOTH = [c.name for c in CORPUS if not c.creased]


@pytest.mark.parametrize("name", SMOOTH)
def test_untouched_piece_stays_where_it_was(runs, name):
    run = runs[name]
    # the bars: mean <= 0.1 %, max <= 0.5 % of the piece's diameter
    assert run.untouched_disp.mean() <= 0.001
    assert run.untouched_disp.max() <= 0.005


@pytest.mark.parametrize("name", SMOOTH)
def test_moved_piece_goes_back(runs, name):
    run = runs[name]
    # the bar: mean distance to where it was <= 0.5 % of the diameter
    assert run.moved_disp.mean() <= 0.005


@pytest.mark.parametrize("name", IDS)
def test_nothing_folds(runs, name):
    run = runs[name]
    assert run.untouched.metrics["folded_pairs"] == 0
    assert run.moved.metrics["folded_pairs"] == 0


@pytest.mark.parametrize("name", IDS)
def test_crease_not_above_the_uncut_surface(runs, name):
    run = runs[name]
    _band(run)
    # the bar: the mean crease at most 0.5 degree above the uncut
    # surface's, by the same measure at the same band (creased cases too:
    # there the crease must not rise)
    assert run.crease_untouched.mean() <= run.crease_uncut.mean() + 0.5
    assert run.crease_moved.mean() <= run.crease_uncut.mean() + 0.5


@pytest.mark.parametrize("name", [c.name for c in CORPUS if c.creased])
def test_creased_cut_is_creased_by_the_measure_and_reported(runs, name):
    run = runs[name]
    _band(run)
    assert run.crease_uncut.max() > CREASED_DEG
    for res in (run.untouched, run.moved):
        # the result says the host was creased there: its report gives the inputs' crease,
        # and a crease the band fits tell from their noise is the inputs' (host_creased),
        # never one the join made (crease)
        report = res.report()
        assert report["metrics"]["input_crease_deg"]["max"] > CREASED_DEG
        codes = [w["code"] for w in report["warnings"]]
        assert "crease" not in codes
        if res.metrics["crease_deg"]["beyond_noise_max"] > CREASED_DEG:
            assert "host_creased" in codes
