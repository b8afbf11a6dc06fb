"""What a join's set-up holds while it factors, and that holding less changes no float."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
import igljoin.solve
from igljoin import linsolve, measure_join, phantoms
from igljoin.terms import ShapeTerm, SmoothJoinTerm, StretchTerm

needs_pardiso = pytest.mark.skipif(
    "pardiso" not in linsolve.available_backends(), reason="mkl (igljoin[pardiso]) missing"
)


@pytest.fixture(scope="module", params=["end_to_end", "partial_patch"])
def sample(request):
    return phantoms.paper_sample(request.param, "equal")


def _solver(s):
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve).solver


def _same(A: sp.csr_matrix, B: sp.csr_matrix) -> bool:
    """The same stored arrays, to the bit (the layout too: later sums read it)."""
    return all(np.array_equal(getattr(A, a), getattr(B, a)) for a in ("data", "indices", "indptr"))


def _blocks_alive_at_factor(monkeypatch, s) -> tuple[int, list]:
    """Terms' quadratic blocks made during a set-up of ``s``, and how many were still held
    (not collected) when each factorization of the set-up started."""
    made, alive = [], []
    for cls in (ShapeTerm, StretchTerm, SmoothJoinTerm):

        def recorded(self, _quadratic=cls.quadratic):
            block = _quadratic(self)
            made.append(weakref.ref(block))
            return block

        monkeypatch.setattr(cls, "quadratic", recorded)
    for cls in (linsolve.FixedQuadratic, linsolve.AugmentedQuadratic):

        def factored(*args, _make=cls):
            gc.collect()
            alive.append(sum(ref() is not None for ref in made))
            return _make(*args)

        monkeypatch.setattr(igljoin.solve, cls.__name__, factored)
    _solver(s)
    return len(made), alive


def test_term_blocks_are_let_go_before_the_factorization(sample, monkeypatch):
    made, alive = _blocks_alive_at_factor(monkeypatch, sample)
    assert made == 3  # shape, stretch and the smooth join's formed block
    assert alive == [0]  # one factorization, every block summed and gone


@needs_pardiso
def test_term_blocks_are_let_go_before_the_augmented_factorization(sample, monkeypatch):
    monkeypatch.setattr(igljoin.solve, "AUGMENT_FROM_COUPLINGS", 0)
    made, alive = _blocks_alive_at_factor(monkeypatch, sample)
    assert made == 2  # shape and stretch: the band block is never formed
    assert alive == [0]


def _listed_sums(terms, n: int) -> tuple:
    """``Σ K_tᵀ W_t K_t`` and ``Σ c_t K_tᵀ W_t K_t`` as sums of a list of blocks (what the
    solver made before it summed them as made)."""
    blocks = [t.quadratic() for t in terms]
    scaled = [t.preconditioner_scale * q for t, q in zip(terms, blocks)]
    return (
        sp.csr_matrix(sum(blocks, sp.csr_matrix((n, n)))),
        sp.csr_matrix(sum(scaled, sp.csr_matrix((n, n)))),
    )


def test_summed_blocks_are_the_sums_of_their_list(sample):
    ls = _solver(sample)
    Q, P = _listed_sums(ls.terms, ls.n)
    assert ls.P is not ls.Q  # the stretch and smooth terms' scales are below 1
    assert _same(ls.Q, Q)
    assert _same(ls.P, P)


@needs_pardiso
def test_the_other_terms_sums_are_made_where_used(sample, monkeypatch):
    monkeypatch.setattr(igljoin.solve, "AUGMENT_FROM_COUPLINGS", 0)
    sums = []

    def recorded(*args, _summed=igljoin.solve._summed, **kwargs):
        out = _summed(*args, **kwargs)
        sums.extend(weakref.ref(m) for m in out if m is not None)
        return out

    monkeypatch.setattr(igljoin.solve, "_summed", recorded)
    js = igljoin.JoinSolver(sample.host, sample.guest, sample.host_curve, sample.guest_curve)
    ls = js.solver
    gc.collect()
    # the set-up made the scaled sum only (the factorization's), and let it go
    assert len(sums) == 1 and sums[0]() is None
    assert not [k for k, v in vars(ls).items() if isinstance(v, sp.spmatrix)]
    # what is made from them later is what the sums kept would have made, to the bit
    wide = ls.wide
    rest_q, rest_p = _listed_sums([t for t in ls.terms if t is not wide], ls.n)
    assert _same(ls.Q, sp.csr_matrix(rest_q + wide.quadratic()))
    assert _same(ls.P, sp.csr_matrix(rest_p + wide.preconditioner_scale * wide.quadratic()))
    X = js.solve().guest.V
    Xc = X - np.mean(X, axis=0)
    KX = wide.K @ Xc
    e_ref = float(np.einsum("ij,ij->", Xc, rest_q @ Xc)) + float(
        np.dot(wide.weights, np.einsum("ij,ij->i", KX, KX))
    )
    assert ls.energy_floor(X, 1e-3) == 1e-3 * 1e-3 * e_ref
    v = np.random.default_rng(0).normal(size=(len(ls.free), 3))
    plain = linsolve.AugmentedQuadratic(rest_q, wide.K, wide.weights, 1.0, ls.fixed)
    assert np.array_equal(ls.plain_factor().solve_free(v), plain.solve_free(v))


def _fits(js) -> list:
    """The rest guest's band fits the solver keeps, by their number of rows."""
    return sorted(v.weights.shape[0] for k, v in js._rest.made.items() if k[0] == "fit")


def test_a_terms_fit_along_the_whole_seam_is_not_kept(monkeypatch):
    # host points inserted into the guest's seam: the term's fit (the whole seam) is not
    # the measures' (the seam vertices on host curve vertices)
    s = phantoms.paper_sample("end_to_end", "equal")
    js = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    part = js.parts[0]
    assert len(part.host_hit) < len(part.seam)
    assert _fits(js) == [len(part.host_hit)]
    res = js.solve()
    # keeping it, as the store did, makes the same rows and the same join, to the bit
    fit = measure_join.RestMeasures.fit

    def kept(self, curve, closed, band, keep=True):
        return fit(self, curve, closed, band)

    monkeypatch.setattr(measure_join.RestMeasures, "fit", kept)
    js_kept = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    assert _fits(js_kept) == [len(part.host_hit), len(part.seam)]
    assert _same(js.terms[-1].K, js_kept.terms[-1].K)
    res_kept = js_kept.solve()
    assert res.energy == res_kept.energy
    assert np.array_equal(res.guest.V, res_kept.guest.V)
    assert np.array_equal(res.crease, res_kept.crease)


def test_a_fit_the_measures_share_is_made_once(monkeypatch):
    # every seam vertex on a host curve vertex: the term's fit is the measures'
    s = phantoms.paper_sample("partial_patch", "equal")
    made = []

    def counted(*args, _band_fit=measure_join.band_fit):
        made.append(len(args[2]))
        return _band_fit(*args)

    monkeypatch.setattr(measure_join, "band_fit", counted)
    js = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    assert made == [len(js.parts[0].seam)]
    assert _fits(js) == made


@needs_pardiso
def test_the_augmented_factorization_holds_the_band_rows_once(sample, monkeypatch):
    monkeypatch.setattr(igljoin.solve, "AUGMENT_FROM_COUPLINGS", 0)
    before, made = [], []

    def live() -> list:
        gc.collect()
        return [m for m in gc.get_objects() if isinstance(m, sp.spmatrix)]

    def augmented(S, *args, _make=linsolve.AugmentedQuadratic):
        before.extend(live())
        before.append(S)
        return _make(S, *args)

    def factored(A, *args, _pardiso=linsolve._Pardiso, **kwargs):
        seen = {id(m) for m in before}
        made.extend(m for m in live() if id(m) not in seen and m is not A)
        return _pardiso(A, *args, **kwargs)

    monkeypatch.setattr(igljoin.solve, "AugmentedQuadratic", augmented)
    monkeypatch.setattr(linsolve, "_Pardiso", factored)
    f = _solver(sample).factor
    S = before[-1]
    # when the factorization starts, the set-up's matrices are the parts the factor keeps
    # (and S's own, which its caller holds): not the rows of positive weight, nor K_f
    # beside K_fᵀ
    kept = (f.Sff, f.Sfb, f.Kb, f.Kft)
    extra = [
        m for m in made if not any(m is k for k in kept) and not np.shares_memory(m.data, S.data)
    ]
    assert extra == []
    # K_f is K_fᵀ's view, and the products through it are the formed K_f's, to the bit
    assert np.shares_memory(f.Kf.data, f.Kft.data)
    Kf = sp.csr_matrix(f.Kft.T)
    for k in (1, 3):
        x = np.random.default_rng(k).normal(size=(len(f.free), k))
        assert np.array_equal(f.Kf @ x, Kf @ x)
        assert np.array_equal(f.matvec(x), f.Sff @ x + f.Kft @ (f.cw[:, None] * (Kf @ x)))


def test_the_shape_and_stretch_terms_share_one_difference_operator(sample):
    shape, stretch = _solver(sample).terms[:2]
    assert isinstance(shape, ShapeTerm) and isinstance(stretch, StretchTerm)
    assert stretch.K is shape.D and stretch.Kt is shape.Dt
    # the operators each made for itself, to the bit
    alone = StretchTerm(np.zeros((shape.n, 3)), stretch.E, 1.0)  # D reads E and n alone
    assert alone.K is not shape.D
    assert _same(alone.K, shape.D) and _same(alone.Kt, shape.Dt)


def test_the_stretch_term_holds_the_shape_terms_rest_edges_where_they_are_its_own(sample):
    js = igljoin.JoinSolver(sample.host, sample.guest, sample.host_curve, sample.guest_curve)
    shape, stretch = js.terms[:2]
    assert stretch.rest is shape.rest_edges
    # they are the edges it made itself, D V0, to the bit
    own = np.ascontiguousarray(stretch.K @ js.corr.V)
    assert np.array_equal(own.view(np.uint64), stretch.rest.view(np.uint64))
    # edges that differ from its own in the sign of a zero alone are not taken
    edges = shape.rest_edges.copy()
    zero = tuple(np.argwhere(edges == 0.0)[0])
    edges[zero] = -edges[zero]
    kept = stretch.rest
    assert not stretch.share_rest(edges) and stretch.rest is kept
