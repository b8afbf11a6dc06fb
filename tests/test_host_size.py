"""A large host costs little: it is checked, selected and measured near its curves only."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import igljoin
from igljoin import phantoms

join_module = importlib.import_module("igljoin.join")  # the module (igljoin.join is the function)


@pytest.fixture(scope="module")
def tall():
    """The paper's patch guest on a wall three times as tall as the paper's (ends 60 mm away)."""
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.6)
    host = phantoms.aortic_wall(
        15.0, 120.0, 120.0, hole_axes=(8.0, 5.0), n_hole=len(s.host_curve), name="wall"
    )
    # the hole is vertices 0..n_hole-1 of both walls (aortic_wall's numbering)
    np.testing.assert_array_equal(host.V[: len(s.host_curve)], s.host.V[s.host_curve])
    return host, s.guest, np.arange(len(s.host_curve))


def _far_face(host, curve):
    """The face farthest from the curve."""
    c = host.V[host.F].mean(axis=1)
    d = np.linalg.norm(c[:, None, :] - host.V[curve][None, :, :], axis=2).min(axis=1)
    return int(np.argmax(d))


def _near_face(host, curve):
    return int(np.flatnonzero(np.isin(host.F, curve).any(axis=1))[0])


def _with_copy_of_face(host, f):
    """``host`` with face ``f`` listed twice (a duplicated face: check_surface refuses it)."""
    return igljoin.Mesh(host.V, np.vstack([host.F, host.F[f : f + 1]]), name="wall")


def test_neighbourhood_gives_the_same_join(tall, monkeypatch):
    host, guest, hc = tall
    whole = igljoin.join(host, guest, hc)
    monkeypatch.setattr(join_module, "HOST_CHECK_ALL_FACES", 0)
    solver = igljoin.JoinSolver(host, guest, hc)
    near = solver._host_near
    # the neighbourhood is a real part of the host, not all of it
    assert near is not None and near.n_faces < 0.6 * host.n_faces
    res = solver.solve()
    # the same selection, factorization and iteration: bit-identical positions
    np.testing.assert_array_equal(res.guest.V, whole.guest.V)
    np.testing.assert_array_equal(res.host_curve, whole.host_curve)
    np.testing.assert_array_equal(res.crease, whole.crease)
    assert res.metrics["host_dihedral_deg"] == whole.metrics["host_dihedral_deg"]
    assert res.metrics["weld"] == whole.metrics["weld"]
    assert res.metrics["self_intersections"] == whole.metrics["self_intersections"]
    assert solver.host_curve.closed and solver.host_curve.loop == -1


def test_a_defect_far_from_the_curve_does_not_stop_a_large_host(tall, monkeypatch):
    host, guest, hc = tall
    bad = _with_copy_of_face(host, _far_face(host, hc))
    with pytest.raises(igljoin.MeshError, match="duplicated"):
        igljoin.join(bad, guest, hc)  # a small host is checked whole
    monkeypatch.setattr(join_module, "HOST_CHECK_ALL_FACES", 0)
    res = igljoin.join(bad, guest, hc)
    assert res.converged and res.metrics["seam_gap"]["relative_max"] < 1e-9


def test_a_defect_near_the_curve_is_reported_as_on_the_whole_host(tall, monkeypatch):
    host, guest, hc = tall
    bad = _with_copy_of_face(host, _near_face(host, hc))
    with pytest.raises(igljoin.MeshError) as whole:
        igljoin.join(bad, guest, hc)
    monkeypatch.setattr(join_module, "HOST_CHECK_ALL_FACES", 0)
    with pytest.raises(igljoin.MeshError) as near:
        igljoin.join(bad, guest, hc)
    assert str(near.value) == str(whole.value)


def test_a_bad_curve_on_a_large_host_gets_the_whole_host_message(tall, monkeypatch):
    host, guest, hc = tall
    broken = hc[[0, 2, 1, *range(3, len(hc))]]
    with pytest.raises(igljoin.CurveError) as whole:
        igljoin.join(host, guest, broken)
    monkeypatch.setattr(join_module, "HOST_CHECK_ALL_FACES", 0)
    with pytest.raises(igljoin.CurveError) as near:
        igljoin.join(host, guest, broken)
    assert str(near.value) == str(whole.value)
