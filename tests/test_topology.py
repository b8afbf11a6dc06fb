"""igljoin.topology on tiny meshes with known answers (its libigl cross-checks are in
test_setup_speed_equivalence.py and test_metrics_speed_equivalence.py)."""

from __future__ import annotations

import numpy as np
import pytest

from igljoin import topology

# two triangles sharing the edge (1, 2)
PAIR = np.array([[0, 1, 2], [2, 1, 3]])
# a closed tetrahedron, consistently oriented
TET = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
BOWTIE = np.array([[0, 1, 2], [0, 3, 4]])  # two triangles touching only at vertex 0
FIN = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # three faces on the edge (0, 1)


def test_edges_of_two_triangles():
    E, side, count = topology.edges(PAIR)
    np.testing.assert_array_equal(E, [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
    np.testing.assert_array_equal(count, [1, 1, 2, 1, 1])
    # side k of face f is row side[k * m + f]: sides (0,1), (1,2), (2,0) of each face
    sides = np.concatenate([PAIR[:, [0, 1]], PAIR[:, [1, 2]], PAIR[:, [2, 0]]])
    np.testing.assert_array_equal(np.sort(sides, axis=1), E[side])


def test_edges_of_a_closed_surface_have_two_faces_each():
    E, _, count = topology.edges(TET)
    assert len(E) == 6 and (count == 2).all()


def test_edges_of_no_faces():
    E, side, count = topology.edges(np.zeros((0, 3), dtype=np.int64))
    assert E.shape == (0, 2) and side.size == 0 and count.size == 0


def test_edges_count_a_fin():
    E, _, count = topology.edges(FIN)
    assert count[(E == [0, 1]).all(axis=1)].tolist() == [3]


@pytest.mark.parametrize(
    "F, n, manifold, fans",
    [
        (PAIR, 4, [1, 1, 1, 1], [1, 1, 1, 1]),
        (TET, 5, [1, 1, 1, 1, 0], [1, 1, 1, 1, 0]),  # vertex 4 is unused
        (BOWTIE, 5, [0, 1, 1, 1, 1], [2, 1, 1, 1, 1]),
    ],
    ids=["pair", "tet-plus-unused", "bowtie"],
)
def test_vertex_manifold_and_fan_counts(F, n, manifold, fans):
    np.testing.assert_array_equal(topology.vertex_manifold(F, n), np.array(manifold, dtype=bool))
    np.testing.assert_array_equal(topology.fan_counts(F, n), fans)


def test_fan_counts_of_two_cones_sharing_their_apex():
    cones = [[0, i, i % 4 + 1] for i in range(1, 5)] + [[0, i % 4 + 5, i] for i in range(5, 9)]
    assert topology.fan_counts(np.array(cones), 9)[0] == 2
    assert topology.fan_counts(np.zeros((0, 3), dtype=np.int64), 3).tolist() == [0, 0, 0]


def test_components_numbered_by_first_face():
    F = np.vstack([BOWTIE + 5, PAIR, [[10, 11, 12]]])  # bow-tie (one piece), pair, lone face
    label, size = topology.components(F, 13)
    np.testing.assert_array_equal(label, [0, 0, 1, 1, 2])
    np.testing.assert_array_equal(size, [2, 2, 1])


def test_repeated_directed_edges_and_orientability():
    assert topology.repeated_directed_edges(TET) == 0
    flipped = TET.copy()
    flipped[0] = flipped[0, ::-1]  # its three edges now run the same way as a neighbour's
    assert topology.repeated_directed_edges(flipped) == 3
    assert topology.orientable(flipped)  # bfs_orient can turn it back
    # a Möbius strip: four quads in a row, the last glued to the first with a twist
    top, bottom = [0, 1, 2, 3, 4], [5, 6, 7, 8, 9]
    quads = [(top[i], top[i + 1], bottom[i + 1], bottom[i]) for i in range(4)]
    quads.append((top[4], bottom[0], top[0], bottom[4]))
    mobius = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))])
    assert not topology.orientable(mobius)


def _repeated_directed_pairs(F, n):
    """:func:`topology.repeated_directed_pairs` given the pairs as mesh validation finds them."""
    half = topology.half_edges(F, n)
    start, count = topology.runs(half[3])
    return topology.repeated_directed_pairs(half, start[count == 2])


def test_repeated_directed_pairs_count_what_the_sort_of_directed_edges_counts():
    # on surfaces whose edges have at most two sides: a grid with random faces turned over
    # (each turned face runs its interior sides as a neighbour does, unless that one is
    # turned too), and the tetrahedron
    assert _repeated_directed_pairs(TET, 4) == 0
    x, y = np.meshgrid(np.arange(9), np.arange(7), indexing="ij")
    a = (x[:-1, :-1] * 7 + y[:-1, :-1]).ravel()
    F = np.concatenate([np.stack([a, a + 7, a + 8], 1), np.stack([a, a + 8, a + 1], 1)])
    rng = np.random.default_rng(2)
    counts = set()
    for share in (0.0, 0.1, 0.5, 1.0):
        G = F.copy()
        turn = rng.uniform(size=len(G)) < share
        G[turn] = G[turn, ::-1]
        want = topology.repeated_directed_edges(G, 63)
        assert _repeated_directed_pairs(G, 63) == want
        counts.add(want)
    assert 0 in counts and len(counts) >= 3  # none, some and many repeated


def test_shared_and_repeated_rows():
    P = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [-0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(topology.shared_rows(P), [True, False, True, True])
    assert topology.repeated_rows(P) == 2  # two rows repeat the first one
    assert topology.repeated_rows(np.zeros((0, 3))) == 0


def test_row_counts_and_runs():
    A = np.array([[1, 2], [0, 3], [1, 2], [1, 2]])
    np.testing.assert_array_equal(topology.row_counts(A, 4), [1, 3])
    start, count = topology.runs(np.array([2, 2, 5, 7, 7, 7]))
    np.testing.assert_array_equal(start, [0, 2, 3])
    np.testing.assert_array_equal(count, [2, 1, 3])
