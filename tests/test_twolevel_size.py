"""The two-level model's coarse system: band rows kept apart; a size guard before the build."""

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import coarse_kernels, linsolve, newton, twolevel
from igljoin.terms import ShapeTerm, SmoothJoinTerm

from .test_twolevel import _left_out_apart, _solver

pardiso = pytest.mark.skipif(
    "pardiso" not in linsolve.available_backends(), reason="the augmented system needs Pardiso"
)


@pytest.fixture(scope="module")
def patch():
    # the two-level tests' patch: the paper's partial patch at resolution 0.5
    return _solver("partial_patch")


def _start(solver):
    return solver.solver.local(solver.initial_guess())[0]


@pardiso
@pytest.mark.parametrize("bending", [False, True])
def test_band_rows_kept_apart_give_the_same_coarse_model(patch, monkeypatch, bending):
    solver = patch
    ls = solver.solver
    state = _start(solver)
    assembled = twolevel.TwoLevelModel(ls, cluster_size=5, bending=bending)
    assembled.refresh(state, 1)
    # the small patch's band rows reach too few clusters for the real threshold: with
    # clusters of 5 they reach 3.2 on average, the shape and stretch rows (one-rings,
    # edges) 1.4 and 1.2, so a threshold of 2 keeps the band rows apart alone
    monkeypatch.setattr(twolevel, "_WIDE_CLUSTERS", 2)
    apart = twolevel.TwoLevelModel(ls, cluster_size=5, bending=bending)
    apart.refresh(state, 1)
    wide = [isinstance(t, SmoothJoinTerm) for t in ls.terms]
    assert apart._wide == wide and any(wide)
    assert isinstance(apart.coarse_factor, linsolve.AugmentedQuadratic)
    H = newton.gauss_newton(ls.terms, state, ls.n)
    free = newton.dofs(ls.free)
    expected = _left_out_apart(apart, (apart.A.T @ H[free][:, free] @ apart.A).toarray())
    got = apart.coarse_matrix().toarray()
    # rounding (1e-12 of the largest entry) plus the ridge of 1e-10 of the mean diagonal
    assert np.abs(got - expected).max() <= 1e-9 * np.abs(expected).max()
    # the count made before the build never falls short of what the factorization holds
    held = apart.coarse_factor.Sff.nnz + apart.coarse_factor.Kf.nnz
    assert apart.coarse_entries >= held
    v = np.random.default_rng(0).standard_normal((len(ls.free), 3))
    a, b = assembled.solve_free(v), apart.solve_free(v)
    # two factorizations of the same A_c, whose ridge allows a condition number near
    # 1e10: their solutions agree to ~1e-7 of the coarse part, far below 1e-5
    assert np.linalg.norm(a - b) <= 1e-5 * np.linalg.norm(a)


def test_the_rows_kept_apart_are_the_factor_rows_on_the_motions(patch):
    # every term's rows K_r ⊗ d on the motions, as a wide term's are kept (the band rows
    # have one direction per row, the stretch term four, K ⊗ I₃ the three unit ones)
    solver = patch
    ls = solver.solver
    state = _start(solver)
    model = twolevel.TwoLevelModel(ls, cluster_size=5, bending=True)
    model.refresh(state, 1)
    A, free, w = model.A, newton.dofs(ls.free), model.motions.shape[2]
    for term, (of_K, _) in zip(ls.terms, model._patterns):
        K = sp.csr_matrix(term.K)
        (_, directions, weights), _ = newton.factor_rows(term, state)
        D = weights.shape[1]
        directions = np.zeros((0, 3, 3)) if directions is None else directions
        values = coarse_kernels.motion_rows_of(
            K.indptr, K.indices, K.data, np.ascontiguousarray(directions), of_K[0], of_K[2],
            model._where, model.motions,
        )  # fmt: skip
        got = twolevel._motion_matrix(values, of_K[0], of_K[1], D, w, model._clusters)
        # the reference: the factors J (K ⊗ I₃ has its rows 3 r + d already; the stretch
        # term's four factors interleaved row by row), times A
        factors = [J for J, _, sign in newton.gauss_newton_factors([term], state, ls.n)]
        factors = [J[:, free] @ A for J in factors[: 1 if D == 3 else D]]
        expected = factors[0].toarray()
        if len(factors) > 1:
            expected = np.stack([F.toarray() for F in factors], 1).reshape(-1, A.shape[1])
        # the same products summed in another order: rounding, 1e-12 of the largest entry
        assert got.shape == expected.shape
        assert np.abs(got.toarray() - expected).max() <= 1e-12 * np.abs(expected).max()


def test_the_count_is_the_coarse_matrix_held(patch):
    solver = patch
    model = twolevel.TwoLevelModel(solver.solver, bending=True)
    model.refresh(_start(solver), 1)
    # the band rows of the small patch reach a few clusters: all assembled, every entry
    # of the coarse matrix counted
    assert not any(model._wide)
    assert model.coarse_entries == model.coarse_matrix().nnz
    # and besides it what the model keeps: one cluster slot per entry of the operators
    # (and of the Laplacian), every free vertex's motions; no factor of the Gauss–Newton
    # model (the additive form projects the operators' rows without forming them)
    slots = sum(len(K[2]) + (0 if L is None else len(L[2])) for K, L in model._patterns)
    assert model.model_entries == model.coarse_entries + slots + model.motions.size
    assert model.factors is None
    # the balancing form keeps the factors for its products with H, and counts them
    balancing = twolevel.TwoLevelModel(solver.solver, bending=True, balancing=True)
    balancing.refresh(_start(solver), 1)
    factors = sum(J.nnz for J, _, _ in balancing.factors)
    assert factors == sum(newton.factor_entries(t) for t in solver.solver.terms)
    assert balancing.model_entries == model.model_entries + factors


def test_the_factors_entries_are_counted_from_the_patterns(patch):
    solver = patch
    ls = solver.solver
    state = _start(solver)
    for term in ls.terms:
        held = sum(J.nnz for J, _, _ in newton.gauss_newton_factors([term], state, ls.n))
        assert newton.factor_entries(term) == held


def test_a_coarse_system_too_large_is_refused_before_it_is_built(patch, monkeypatch):
    solver = patch
    ls = solver.solver
    monkeypatch.setattr(twolevel, "MAX_MODEL_ENTRIES", 100)

    def expensive(*args, **kwargs):
        raise AssertionError("the model was built past the guard")

    # the model's values are computed term after term by factor_rows (and by
    # gauss_newton_factors for the balancing form): neither may run
    monkeypatch.setattr(twolevel, "factor_rows", expensive)
    monkeypatch.setattr(twolevel, "gauss_newton_factors", expensive)
    model = twolevel.TwoLevelModel(ls)
    with pytest.raises(igljoin.OptionsError, match="MAX_MODEL_ENTRIES.*preconditioner='factored'"):
        model.refresh(_start(solver), 1)
    assert model.model_entries > 100 and model.factorizations == 0
    # refused again at the next refresh, not built (expensive would raise), and the size it
    # would take given to two figures below 1 GB (not "0 GB")
    with pytest.raises(igljoin.OptionsError, match=r"about [\d.]+(e-\d+)? GB at its first"):
        model.refresh(_start(solver), 1)
    # the join with the explicit option is refused with the same message
    fresh = _solver("partial_patch")
    with pytest.raises(igljoin.OptionsError, match="model would hold"):
        fresh.solve(preconditioner="two-level")


def test_auto_keeps_the_factored_form_when_the_coarse_system_is_too_large(monkeypatch):
    solver = _solver("partial_patch")
    default = solver.solve(preconditioner="factored")
    assert solver.last_model is None
    monkeypatch.setattr(twolevel, "AUTO_FROM_VERTICES", 0)
    # auto's own limit, below the explicit option's: a model the explicit option would
    # build is not built by auto
    monkeypatch.setattr(twolevel, "AUTO_MAX_MODEL_ENTRIES", 100)
    model = twolevel.preferred_model(solver.solver, igljoin.JoinOptions(preconditioner="auto"))
    assert not model.refresh(_start(solver), 1)
    assert "AUTO_MAX_MODEL_ENTRIES = 100 " in model.fallback and model.factorizations == 0
    assert model.model_entries < twolevel.MAX_MODEL_ENTRIES
    auto = solver.solve(preconditioner="auto")
    # the fallback is P alone: the very iterations of the factored form
    assert auto.iterations == default.iterations
    assert auto.energy[-1] == default.energy[-1]
    # and the solver keeps the model, which says why it kept P
    assert "AUTO_MAX_MODEL_ENTRIES" in solver.last_model.fallback
    assert solver.last_run.stats["model_builds"] == 0
    # so do the result and its report (the factored join has no model to speak of)
    said = auto.report()["coarse_model"]
    assert not said["in_use"] and said["builds"] == 0
    assert "AUTO_MAX_MODEL_ENTRIES" in said["fallback"]
    assert default.report()["coarse_model"] == {"in_use": False, "builds": 0, "fallback": None}


def test_a_stacked_operators_clusters_are_counted_block_by_block(patch):
    ls = patch.solver
    shape = ls.terms[0]
    assert isinstance(shape, ShapeTerm) and shape.rotation_aware
    shape._K = None  # as the set-up leaves it
    labels = np.full(ls.n, -1, dtype=np.int64)
    labels[ls.free] = np.arange(len(ls.free)) % 7
    of_K, rows, nnz = twolevel._operator_clusters(shape, labels)
    assert shape._K is None  # the stack is not made for the count
    # the stack's own clusters, the same integers
    K = shape.K
    expected = coarse_kernels.row_clusters(K.indptr, K.indices, labels, 1)
    assert (rows, nnz) == (K.shape[0], K.nnz)
    for got, want in zip(of_K, expected):
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_a_model_that_falls_back_lets_its_patterns_go(monkeypatch):
    solver = _solver("partial_patch")
    shape = solver.solver.terms[0]
    monkeypatch.setattr(twolevel, "AUTO_FROM_VERTICES", 0)
    monkeypatch.setattr(twolevel, "AUTO_MAX_MODEL_ENTRIES", 100)
    model = twolevel.preferred_model(solver.solver, igljoin.JoinOptions(preconditioner="auto"))
    assert not model.refresh(_start(solver), 1) and model.fallback
    # nothing a build would read is held: not the patterns, the cache of the rotations'
    # pattern, nor the shape term's stacked operator
    assert model._patterns is None and model._blocks is None and model._cache == {}
    assert shape._K is None
    # and it stays P alone
    assert not model.refresh(_start(solver), 1) and model.factorizations == 0


@pardiso
def test_a_singular_coarse_system_is_refused_with_the_way_out():
    # A_c = S + Uᵀ W U of rank 1 on four unknowns: Pardiso perturbs the zero pivots, and the
    # probe solve's residual (of order 1) gives it away
    S = sp.csr_matrix((4, 4))
    U = sp.csr_matrix(np.array([[1.0, 1.0, 0.0, 0.0]]))
    with pytest.raises(igljoin.SolveError, match="coarse system.*preconditioner='factored'"):
        twolevel._CoarseAugmented(S, U, np.ones(1))
    # the same system made definite by its S is factored, and solves A_c x = b
    S = sp.identity(4, format="csr")
    f = twolevel._CoarseAugmented(S, U, np.ones(1))
    b = np.arange(1.0, 5.0)[:, None]
    A = (S + U.T @ U).toarray()
    # a 4 x 4 LDLᵀ solve: rounding, far below 1e-12
    assert np.abs(A @ f.solve_free(b) - b).max() <= 1e-12 * np.abs(b).max()


def _coarse_and_base(patch):
    """The partial patch's coarse factor with its band rows kept apart, and the base class
    made on the same parts (``S``, ``U``, ``W``, no fixed rows)."""
    model = twolevel.TwoLevelModel(patch.solver, cluster_size=5)
    model.refresh(_start(patch), 1)
    coarse = model.coarse_factor
    base = linsolve.AugmentedQuadratic(
        coarse.Sff, coarse.Kf, coarse.cw, 1.0, np.zeros(0, dtype=np.int64)
    )
    return coarse, base


@pardiso
def test_the_coarse_factor_has_every_field_the_base_sets(patch, monkeypatch):
    # the small patch's band rows reach too few clusters for the real threshold (see
    # test_band_rows_kept_apart_give_the_same_coarse_model): 2 keeps them apart alone
    monkeypatch.setattr(twolevel, "_WIDE_CLUSTERS", 2)
    coarse, base = _coarse_and_base(patch)
    assert type(coarse) is twolevel._CoarseAugmented
    assert set(vars(base)) <= set(vars(coarse))
    assert base.n == coarse.n and base.free.tolist() == coarse.free.tolist()
    # a field the base's one setter gains is one the subclass has too
    setter = linsolve.AugmentedQuadratic._set_parts

    def with_a_new_field(self, **parts):
        setter(self, **parts)
        self.new_field = parts["n"]

    monkeypatch.setattr(linsolve.AugmentedQuadratic, "_set_parts", with_a_new_field)
    coarse, base = _coarse_and_base(patch)
    assert coarse.new_field == base.new_field == base.n


@pytest.fixture(scope="module")
def patch30k():
    # a 30k-vertex patch (the benchmark's patch phantom, 1,180 guest vertices at resolution
    # 1, at 30,000): three of its clusters have three vertices, whose bending motions the
    # rigid ones span
    return igljoin.phantoms.paper_sample(
        "partial_patch", "equal", guest_resolution=float(np.sqrt(30_000 / 1180))
    )


@pardiso
def test_auto_keeps_its_model_where_rigid_motions_span_some_bending_ones(patch30k):
    s = patch30k
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    auto = solver.solve()
    model = solver.last_model
    assert auto.converged and model.fallback is None and not model.unsound
    assert solver.last_run.stats["model_builds"] >= 1
    # whole clusters' bending motions left out, their columns zero
    out = model.left_out
    assert out.size and out.size % 3 == 0 and np.all(out % 9 >= 6)
    clusters = np.unique(out // 9)
    assert not model.motions[np.isin(model.labels, clusters)][:, :, 6:].any()
    assert np.bincount(model.labels)[clusters].max() < 6  # flat clusters of few vertices
    factored = solver.solve(preconditioner="factored")
    # the same minimum within the benchmark's convergence gap (1e-6; measured -1.7e-7), in
    # fewer iterations (measured 33 against 150)
    assert abs(auto.energy[-1] - factored.energy[-1]) <= 1e-6 * factored.energy[-1]
    assert auto.iterations < factored.iterations


@pardiso
def test_auto_goes_on_with_p_when_its_coarse_system_cannot_be_factored(patch30k, monkeypatch):
    # the same patch with every bending motion kept: its coarse system has pivots Pardiso
    # perturbs and the probe solve refuses it; before, this default join failed with that
    # SolveError
    monkeypatch.setattr(twolevel, "SPANNED_BENDING", -np.inf)
    s = patch30k
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    assert len(solver.solver.free) >= twolevel.AUTO_FROM_VERTICES
    auto = solver.solve()
    assert auto.converged and solver.last_run.stats["model_builds"] == 0
    assert "could not be factored" in solver.last_model.fallback
    assert "factored form alone" in solver.last_model.fallback
    # its values failed, not its size: the next solve would make a new model, not keep it
    assert solver.last_model.unsound
    kept = twolevel.preferred_model(solver.solver, solver.options, solver.last_model)
    assert kept is not solver.last_model and kept.labels is None
    # P alone from the first iteration: the factored form's very iterations; and a solve
    # with P alone lets the kept model go
    factored = solver.solve(preconditioner="factored")
    assert auto.iterations == factored.iterations and auto.energy == factored.energy
    assert solver._model is None
    # the same model without the fallback refuses it, naming the way out, and tries again
    # at the next run's start instead of going on without a coarse factorization
    model = twolevel.TwoLevelModel(solver.solver, **twolevel.AUTO_MODEL)
    for _ in range(2):
        with pytest.raises(igljoin.SolveError, match="preconditioner='factored'"):
            model.refresh(_start(solver), 1)


def test_a_join_reports_its_coarse_model():
    solver = _solver("partial_patch")
    first = solver.solve(preconditioner="two-level")
    assert first.report()["coarse_model"] == {"in_use": True, "builds": 1, "fallback": None}
    # the explicit two-level model is built once per solve (it has no rebuild angle)
    again = solver.solve()
    assert again.coarse_model == {"in_use": True, "builds": 1, "fallback": None}
