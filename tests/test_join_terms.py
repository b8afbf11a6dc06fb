"""The term table of a join: which terms are built, in which order, and the order's one rule."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import igljoin
from igljoin import phantoms
from igljoin.join_terms import TERMS
from igljoin.options import JoinOptions
from igljoin.terms import ShapeTerm, SmoothJoinTerm, StretchTerm, check_order


@pytest.fixture(scope="module")
def patch():
    """The paper's partial patch at half resolution (about 330 guest vertices)."""
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.5)


def _terms(s, **options):
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)
    return solver.terms


def test_every_table_row_is_switched_by_a_weight_option():
    weights = {f.name for f in dataclasses.fields(JoinOptions) if f.name.endswith("_weight")}
    assert [name for name, _ in TERMS] == ["shape_weight", "stretch_weight", "smooth_weight"]
    assert {name for name, _ in TERMS} == weights


def test_terms_come_in_table_order_and_a_zero_weight_drops_its_row(patch):
    assert [type(t) for t in _terms(patch)] == [ShapeTerm, StretchTerm, SmoothJoinTerm]
    assert [type(t) for t in _terms(patch, stretch_weight=0.0)] == [ShapeTerm, SmoothJoinTerm]
    assert [type(t) for t in _terms(patch, shape_weight=0.0)] == [StretchTerm, SmoothJoinTerm]
    # smooth=False switches the smooth join off whatever its weight
    assert [type(t) for t in _terms(patch, smooth=False)] == [ShapeTerm, StretchTerm]


def test_the_stretch_term_reads_the_rotations_the_shape_term_sets(patch):
    shape, stretch, smooth = _terms(patch)
    assert shape.sets_rotations and not shape.reads_rotations
    assert stretch.reads_rotations and not stretch.sets_rotations
    assert not smooth.sets_rotations and not smooth.reads_rotations
    # the paper's fixed Laplacian coordinates fit no rotations
    assert not _terms(patch, rotation_aware=False)[0].sets_rotations


def test_check_order_refuses_a_reader_before_its_setter(patch):
    shape, stretch, smooth = _terms(patch)
    check_order([shape, stretch, smooth])
    check_order([stretch, smooth])  # nothing sets rotations: the stretch term works without
    with pytest.raises(ValueError, match="stretch term reads the rotations the shape term sets"):
        check_order([stretch, shape, smooth])


def test_a_join_without_the_shape_term_still_converges(patch):
    res = igljoin.join(patch.host, patch.guest, patch.host_curve, patch.guest_curve,
                       shape_weight=0.0)  # fmt: skip
    assert res.converged
    assert np.isfinite(res.guest.V).all()
