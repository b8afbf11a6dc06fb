"""Ground truth on a real scan: cut a piece out, move it, join it back."""

from __future__ import annotations

import numpy as np
import pytest

import igljoin
from igljoin import metrics
from igljoin.seam_geometry import SeamGeometry

from .cuts import cut_piece, rigid_motion, sample_mesh_dir

pytest.importorskip("pymeshlab")  # ships the real test meshes

N_CUTS = 8


@pytest.fixture(scope="module")
def bunny():
    return igljoin.read_mesh(sample_mesh_dir() / "bunny.obj")


def _cuts(mesh, count, seed=1):
    """The first ``count`` clean disk cuts of a seeded random sequence (none skipped by hand)."""
    rng = np.random.default_rng(seed)
    size = float(np.linalg.norm(np.ptp(mesh.V, axis=0)))
    found = []
    while len(found) < count:
        center = int(rng.integers(mesh.n_vertices))
        radius = size * rng.uniform(0.05, 0.2)
        cut = cut_piece(mesh, center, radius)
        if cut is not None:
            found.append((center, radius, cut))
    return found


@pytest.fixture(scope="module")
def rejoined(bunny):
    out = []
    for i, (center, radius, cut) in enumerate(_cuts(bunny, N_CUTS)):
        # rotation >= 30 degrees and a shift of 25 % of the piece's size
        R, t = rigid_motion(i, cut.diameter, angle_deg=40.0, shift=0.25)
        moved = igljoin.Mesh(cut.piece.V @ R.T + t, cut.piece.F)
        res = igljoin.join(cut.host, moved, cut.host_curve, None, smooth=True)
        uncut = metrics.crease_angles(
            SeamGeometry(
                cut.host.V,
                cut.host.F,
                cut.host_curve,
                cut.piece.V,
                cut.piece.F,
                cut.piece_at_host,
                True,
            )
        )
        out.append((center, radius, cut, res, uncut))
    return out


def test_cuts_differ_in_place_and_size(rejoined):
    centers = {c for c, *_ in rejoined}
    sizes = [cut.piece.n_vertices for _, _, cut, _, _ in rejoined]
    assert len(centers) == N_CUTS
    assert max(sizes) > 3 * min(sizes)


@pytest.mark.parametrize("i", range(N_CUTS))
def test_piece_goes_back_where_it_was(rejoined, i):
    _, _, cut, res, _ = rejoined[i]
    n = cut.piece.n_vertices
    dist = np.linalg.norm(res.guest.V[:n] - cut.piece.V, axis=1).mean()
    # the bound: mean distance <= 0.5 % of the piece's diameter
    assert dist <= 0.005 * cut.diameter


@pytest.mark.parametrize("i", range(N_CUTS))
def test_crease_no_worse_than_the_uncut_surface(rejoined, i):
    _, _, cut, res, uncut = rejoined[i]
    # the bound: at most 1 degree above the uncut mesh's own crease on that curve
    assert res.crease.mean() <= uncut.mean() + 1.0
