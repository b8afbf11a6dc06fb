"""The term table of a join: which terms are built, in which order, and the order's one rule."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import phantoms, terms
from igljoin.join_terms import TERMS
from igljoin.options import JoinOptions
from igljoin.terms import LocalState, ShapeTerm, SmoothJoinTerm, StretchTerm, check_order


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


def _same_csr(a, b):
    """The same sparse matrix to the bit: shape, layout (row pointers, column order), values."""
    assert a.shape == b.shape
    for name in ("indptr", "indices", "data"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y)


@pytest.mark.parametrize("mode", ["band", "robust", "paper"])
def test_a_terms_quadratic_is_the_straightforward_product_to_the_bit(mode):
    # Kᵀ W K as the straightforward expression gives it, values and layout: later sums
    # read the layout (a row of a sparse product is summed in its stored order), so a
    # quadratic that differed in either would change the join's answers
    for key in [("end_to_end", "equal"), ("partial_patch", "longer")]:
        s = phantoms.paper_sample(*key)
        solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode=mode)
        smooth = solver.terms[-1]
        assert isinstance(smooth, SmoothJoinTerm)
        K, w = smooth.K, smooth.weights
        _same_csr(smooth.quadratic(), sp.csr_matrix(K.T @ sp.diags(w) @ K))
        # the local step's Kᵀ W (made by the numpy step) is the expression's too, as the
        # quadratic's first factor is
        smooth.compiled = False
        smooth.local(LocalState(solver.initial_guess()))
        _same_csr(smooth._KtW, sp.csr_matrix(K.T @ sp.diags(w)))
        # rows of weight 0 (a seam vertex the term leaves alone): the product keeps none of
        # their entries
        w = np.where(np.arange(len(w)) % 3 == 0, 0.0, w)
        _same_csr(terms._gram(K, w), sp.csr_matrix(K.T @ sp.diags(w) @ K))
        _same_csr(terms._weighted_transpose(K, w), sp.csr_matrix(K.T @ sp.diags(w)))


def test_the_quadratic_of_a_matrix_with_duplicate_entries_is_the_straightforward_product():
    # duplicates are summed where the product meets them, so the expression itself runs
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, 30, 400), rng.integers(0, 50, 400)
    K = sp.csr_matrix((rng.normal(size=400), (rows, cols)), shape=(30, 50))
    # the same matrix as a new object around K's own arrays (no copy)
    K = sp.csr_matrix((K.data, K.indices, K.indptr), shape=K.shape)
    dup = sp.csr_matrix(
        (np.concatenate([K.data, K.data[:5]]), np.concatenate([K.indices, K.indices[:5]]),
         np.concatenate([K.indptr[:1], K.indptr[1:] + 5])),
        shape=K.shape,
    )  # fmt: skip
    assert not dup.has_canonical_format
    w = rng.uniform(0.5, 2.0, 30)
    _same_csr(terms._gram(dup, w), sp.csr_matrix(dup.T @ sp.diags(w) @ dup))
    _same_csr(terms._gram(K, w), sp.csr_matrix(K.T @ sp.diags(w) @ K))
    _same_csr(terms._weighted_transpose(dup, w), sp.csr_matrix(dup.T @ sp.diags(w)))
    _same_csr(terms._weighted_transpose(K, w), sp.csr_matrix(K.T @ sp.diags(w)))
