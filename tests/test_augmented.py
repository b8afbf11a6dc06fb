"""The band smooth-join rows solved through the augmented system, without their block."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
import igljoin.solve
import igljoin.terms
from igljoin import linsolve, phantoms
from igljoin.errors import SolveError

pytestmark = pytest.mark.skipif(
    "pardiso" not in linsolve.available_backends(), reason="mkl (igljoin[pardiso]) missing"
)


def _solver(s, **options):
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)


@pytest.fixture(scope="module", params=["partial_patch", "end_to_end"])
def sample(request):
    return phantoms.paper_sample(request.param, "equal")


@pytest.fixture
def forced(monkeypatch):
    """Every band term goes through the augmented system, whatever its size."""
    monkeypatch.setattr(igljoin.solve, "AUGMENT_FROM_COUPLINGS", 0)


def _rel(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_paper_samples_keep_the_formed_block(sample):
    ls = _solver(sample).solver
    # a few thousand pairs at the paper's size, far below the threshold
    assert ls.wide is None
    assert isinstance(ls.factor, linsolve.FixedQuadratic)


def test_augmented_solves_equal_the_formed_block_solves(sample, forced):
    ls = _solver(sample).solver
    assert ls.wide is not None and isinstance(ls.factor, linsolve.AugmentedQuadratic)
    assert ls.backend == "pardiso"
    rng = np.random.default_rng(1)
    for aug, formed in ((ls.factor, ls.P), (ls.plain_factor(), ls.Q)):
        ref = linsolve.FixedQuadratic(formed, ls.fixed, "cholespy")
        v = rng.normal(size=(len(ls.free), 3))
        # 1e-10 relative: both factor the same SPD system (condition 6e3-4e4 on these
        # samples); measured 6e-15 to 4e-14, the rest is margin for other BLAS
        assert _rel(aug.solve_free(v), ref.solve_free(v)) <= 1e-10
        B = rng.normal(size=(ls.n, 3))
        bc = rng.normal(size=(len(ls.fixed), 3))
        X = aug.solve(B, bc)
        np.testing.assert_array_equal(X[ls.fixed], bc)
        assert _rel(X, ref.solve(B, bc)) <= 1e-10
        # the solve's own residual against Q_ff applied without forming it
        x = aug.solve_free(v)
        assert aug.residual(x, v) <= 1e-10  # same reason as above
        # 1e-12: two sums of the same products (measured 2e-15 to 6e-15)
        assert _rel(aug.matvec(x), ref.Qff @ x) <= 1e-12


def test_a_join_through_the_augmented_system_reaches_the_same_energy(sample, monkeypatch):
    formed = igljoin.join(sample.host, sample.guest, sample.host_curve, sample.guest_curve)
    monkeypatch.setattr(igljoin.solve, "AUGMENT_FROM_COUPLINGS", 0)
    js = _solver(sample)
    aug = js.solve()
    assert js.solver.wide is not None
    assert aug.converged and aug.iterations == formed.iterations
    # 1e-9 relative: the same iteration, the back-solves differing by rounding only
    # (measured 2e-16 and 2e-14 on these two samples)
    assert abs(aug.energy[-1] - formed.energy[-1]) <= 1e-9 * formed.energy[-1]
    # the energy floor from the operators equals tr(X̄ᵀ Q X̄) with Q formed
    X = aug.guest.V
    floor = js.solver.energy_floor(X, 1e-3)
    Xc = X - X.mean(axis=0)
    # 1e-12 relative: the same sum of squares, grouped differently
    assert floor == pytest.approx(1e-6 * np.einsum("ij,ij->", Xc, js.solver.Q @ Xc), rel=1e-12)


def test_matrices_are_formed_only_on_request(sample, forced):
    ls = _solver(sample).solver
    assert ls._Q is None and ls._P is None
    (band,) = [t for t in ls.terms if t is ls.wide]
    direct = sum((t.quadratic() for t in ls.terms), sp.csr_matrix((ls.n, ls.n)))
    # 1e-12 relative: the same sum in another order
    assert abs(ls.Q - direct).max() <= 1e-12 * abs(direct).max()
    assert abs(ls.P - ls.Q).max() > 0  # the preconditioner scales are not all 1
    assert band.preconditioner_scale < 1.0


def test_explicit_backends_keep_the_formed_block(sample, forced):
    # the augmented system needs Pardiso's indefinite factorization
    ls = _solver(sample, linear_solver="cholespy").solver
    assert ls.wide is None and ls.backend == "cholespy"


def test_the_size_guard_applies_only_to_a_formed_block(sample, forced, monkeypatch):
    ls = _solver(sample).solver
    (band,) = [t for t in ls.terms if t is ls.wide]
    monkeypatch.setattr(igljoin.terms, "MAX_BAND_COUPLINGS", (band.K.T @ band.K).nnz // 2)
    js = _solver(sample)  # the block is never formed: nothing to refuse
    assert js.solve().converged
    with pytest.raises(igljoin.OptionsError, match="smooth_band="):
        js.solver.P  # noqa: B018  (forming it is refused)


def test_an_unheld_vertex_is_refused():
    # a path 0-1-2 held at 0 and a vertex 3 that no term holds
    S = sp.csr_matrix(
        np.array(
            [[1.0, -1.0, 0.0, 0.0], [-1.0, 2.0, -1.0, 0.0], [0.0, -1.0, 1.0, 0.0], [0, 0, 0, 0]]
        )
    )
    K = sp.csr_matrix(np.array([[0.0, 1.0, -1.0, 0.0]]))
    with pytest.raises(SolveError, match="not held"):
        linsolve.AugmentedQuadratic(S, K, np.ones(1), 0.5, np.array([0]))


def test_rows_of_zero_weight_are_left_out():
    S = sp.diags([2.0, 2.0, 2.0, 2.0]) - sp.eye(4, k=1) - sp.eye(4, k=-1)
    K = sp.csr_matrix(np.array([[0.0, 1.0, -1.0, 0.0], [1.0, 0.0, 0.0, -1.0]]))
    w = np.array([3.0, 0.0])
    a = linsolve.AugmentedQuadratic(S, K, w, 0.5, np.array([0]))
    assert a.cw.tolist() == [1.5]
    ref = linsolve.FixedQuadratic(S + 0.5 * K.T @ sp.diags(w) @ K, np.array([0]), "igl")
    B = np.arange(8.0).reshape(4, 2)
    bc = np.array([[1.0, -1.0]])
    # 1e-12 relative: a 3 x 3 SPD system, both exact to rounding
    assert _rel(a.solve(B, bc), ref.solve(B, bc)) <= 1e-12


def test_the_stiffness_bound_holds_without_forming_q(sample, forced, monkeypatch):
    """With the band block apart the floor's bound is made from the sum set-up factored and
    the band rows, and a join whose energy stays above it never sums the other terms
    again for the floor."""
    from scipy.sparse.linalg import eigsh

    from igljoin.solve import _FloorTest

    js = _solver(sample)
    ls = js.solver
    assert ls.wide is not None
    # the other terms' part at set-up, the band rows' part only once asked
    assert ls._rest_bound is not None and ls._stiffness_bound is None
    made = []
    real_rest = ls._rest
    monkeypatch.setattr(ls, "_rest", lambda scaled: made.append(scaled) or real_rest(scaled))
    res = js.solve()
    assert res.converged and made == []
    bound = ls.stiffness_bound()
    largest = eigsh(ls.Q, k=1, which="LA", return_eigenvectors=False)[0]
    # a bound (at most ~2.3x above on the paper samples, measured): 1e-9 relative for
    # the eigensolver's own rounding
    assert largest <= bound * (1.0 + 1e-9) and bound < 4.0 * largest
    # the floor test answers as before: e <= floor, the floor made only under the bound
    X, tol = js.initial_guess(), js.options.energy_tolerance
    floor = ls.energy_floor(X, tol)
    test = _FloorTest(ls, X, tol)
    assert floor <= test.bound < np.inf
    for e in (0.0, floor, np.nextafter(floor, np.inf), 10 * test.bound):
        assert _FloorTest(ls, X, tol).reached(e) == (e <= floor), e
    test.reached(2.0 * test.bound)
    assert test.floor is None
