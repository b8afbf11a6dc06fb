"""The solver: linear-solver backends, exact rotations, energy descent, convergence, limits."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

import igljoin
from igljoin import linsolve, phantoms
from igljoin.rotations import fit_rotations, fit_rotations_igl
from igljoin.start import path_prediction
from igljoin.terms import LocalState, ShapeTerm, StretchTerm, Term

HAVE_CHOLESPY = "cholespy" in linsolve.available_backends()
HAVE_PARDISO = "pardiso" in linsolve.available_backends()
needs_cholespy = pytest.mark.skipif(not HAVE_CHOLESPY, reason="cholespy (igljoin[fast]) missing")
#: The optional backends, each skipped where its package is missing.
OPTIONAL_BACKENDS = [
    pytest.param("cholespy", marks=needs_cholespy),
    pytest.param(
        "pardiso",
        marks=pytest.mark.skipif(not HAVE_PARDISO, reason="mkl (igljoin[pardiso]) missing"),
    ),
]


@pytest.fixture(scope="module")
def patch():
    """The paper's partial patch at half resolution (about 330 guest vertices)."""
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.5)


@pytest.fixture(scope="module")
def tube():
    """The paper's end-to-end sample at half resolution (about 600 guest vertices)."""
    return phantoms.paper_sample("end_to_end", "shorter", resolution=0.5)


def _solver(s, **options):
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)


def _size(s) -> float:
    return float(np.linalg.norm(np.ptp(s.guest.V, axis=0)))


# -- linear-solver backends ----------------------------------------------------------------


@pytest.mark.parametrize("backend", OPTIONAL_BACKENDS)
def test_backends_give_the_same_back_substitution(tube, backend):
    solver = _solver(tube)
    Q, fixed = solver.solver.Q, solver.solver.fixed
    a = linsolve.FixedQuadratic(Q, fixed, "igl")
    b = linsolve.FixedQuadratic(Q, fixed, backend)
    assert b.backend == backend
    rng = np.random.default_rng(0)
    B = rng.normal(size=(Q.shape[0], 3))
    bc = rng.normal(size=(len(fixed), 3))
    xa, xb = a.solve(B, bc), b.solve(B, bc)
    # 1e-8 relative: the bound; two Cholesky factorizations of the same
    # well-conditioned SPD matrix differ only by rounding (~1e-13 here)
    assert np.abs(xa - xb).max() <= 1e-8 * np.abs(xa).max()
    np.testing.assert_array_equal(xa[fixed], bc)
    np.testing.assert_array_equal(xb[fixed], bc)
    v = rng.normal(size=(len(a.free), 2))
    assert np.abs(a.solve_free(v) - b.solve_free(v)).max() <= 1e-8 * np.abs(a.solve_free(v)).max()


@pytest.mark.parametrize("backend", OPTIONAL_BACKENDS)
@pytest.mark.parametrize("name", ["patch", "tube"])
def test_backends_give_the_same_join(name, backend, request):
    s = request.getfixturevalue(name)
    a = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, linear_solver="igl")
    b = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, linear_solver=backend)
    # 1e-8 of the guest size: the bound; the iterations are the same and
    # only the rounding of the back-substitutions differs (measured ~1e-15)
    assert a.iterations == b.iterations
    assert np.abs(a.guest.V - b.guest.V).max() <= 1e-8 * _size(s)


def test_backend_choice():
    assert linsolve.resolve_backend("igl") == "igl"
    expected = "cholespy" if HAVE_CHOLESPY else "igl"
    assert linsolve.resolve_backend("auto") == expected
    # "auto" by size: Pardiso from PARDISO_FROM_NNZ nonzeros on, where it is installed
    small = linsolve.PARDISO_FROM_NNZ - 1
    assert linsolve.resolve_backend("auto", small) == expected
    large = "pardiso" if HAVE_PARDISO else expected
    assert linsolve.resolve_backend("auto", linsolve.PARDISO_FROM_NNZ) == large
    with pytest.raises(igljoin.OptionsError, match="linear_solver"):
        linsolve.resolve_backend("umfpack")
    with pytest.raises(igljoin.OptionsError, match="linear_solver"):
        igljoin.JoinOptions(linear_solver="umfpack")


@pytest.mark.parametrize("backend, extra", [("cholespy", "fast"), ("pardiso", "pardiso")])
def test_a_missing_backend_names_its_extra(monkeypatch, backend, extra):
    # as if the package were not installed
    monkeypatch.setattr(linsolve, "_installed", lambda backend: backend == "igl")
    with pytest.raises(igljoin.MissingExtraError, match=rf"pip install 'igljoin\[{extra}\]'"):
        linsolve.FixedQuadratic(sp.eye(3), np.array([0]), backend)
    assert linsolve.resolve_backend("auto", linsolve.PARDISO_FROM_NNZ) == "igl"


def test_pardiso_is_missing_without_mkl(monkeypatch):
    monkeypatch.setattr(linsolve, "_mkl_rt_path", lambda: None)
    assert "pardiso" not in linsolve.available_backends()
    with pytest.raises(igljoin.MissingExtraError, match="mkl"):
        linsolve.resolve_backend("pardiso")


def test_backend_solves_a_small_system_exactly():
    # 1-D Laplacian with both ends fixed: the solution is the straight line
    Q = sp.diags([2.0] * 5) - sp.eye(5, k=1) - sp.eye(5, k=-1)
    for backend in linsolve.available_backends():
        f = linsolve.FixedQuadratic(Q, np.array([0, 4]), backend)
        x = f.solve(np.zeros((5, 1)), np.array([[0.0], [4.0]]))
        # exact up to rounding of a 3x3 Cholesky
        np.testing.assert_allclose(x[:, 0], [0, 1, 2, 3, 4], atol=1e-12)


@pytest.mark.parametrize("backend", ["igl", *OPTIONAL_BACKENDS])
def test_an_unheld_vertex_is_refused_by_every_backend(backend):
    # vertex 2 is held by nothing (its row and column are zero): not factorable
    Q = sp.diags([2.0, 2.0, 0.0, 2.0, 2.0]) - sp.eye(5, k=1) - sp.eye(5, k=-1)
    Q = sp.csr_matrix(Q)
    Q[1, 2] = Q[2, 1] = Q[2, 3] = Q[3, 2] = 0.0
    with pytest.raises(igljoin.SolveError, match="touches the seam"):
        linsolve.FixedQuadratic(Q, np.array([0]), backend)


def test_changing_the_backend_refactors(patch):
    solver = _solver(patch, linear_solver="igl")
    solver.solve(max_iterations=2)
    assert solver.solver.backend == "igl"
    solver.solve(max_iterations=2, linear_solver="auto")
    assert solver.factorizations == 2
    assert solver.solver.backend == linsolve.resolve_backend("auto")


# -- rotations -------------------------------------------------------------------------------


def _covariances(n, seed):
    """Seeded covariances A = R diag(σ) Vᵀ, a tenth of them reflections (det A < 0)."""
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    V = Rotation.random(n, random_state=seed + 1).as_matrix()
    sigma = np.sort(rng.uniform(0.2, 3.0, size=(n, 3)), axis=1)[:, ::-1]
    sigma[: n // 10, 2] *= -1.0
    A = np.einsum("nij,nj,nkj->nik", R, sigma, V)
    return A.transpose(1, 2, 0).copy()


@pytest.mark.parametrize("start", ["near", "far", "identity"])
def test_rotations_match_libigl(start):
    A = _covariances(2000, seed=3)
    ref = fit_rotations_igl(A)
    n = A.shape[2]
    if start == "near":
        turn = Rotation.from_rotvec(1e-3 * np.random.default_rng(1).normal(size=(n, 3)))
        R0 = (Rotation.from_matrix(ref.transpose(2, 0, 1)) * turn).as_matrix()
    elif start == "far":
        R0 = Rotation.random(n, random_state=7).as_matrix()
    else:
        R0 = np.broadcast_to(np.eye(3), (n, 3, 3))
    R = fit_rotations(A, np.ascontiguousarray(R0.transpose(1, 2, 0)))
    # 1e-12: both are the unique maximiser to rounding (Newton stops one quadratic
    # step past an increment of 1e-7, i.e. at ~1e-14; vertices it cannot settle
    # go to libigl itself)
    assert np.abs(R - ref).max() <= 1e-12
    # proper rotations
    Rn = R.transpose(2, 0, 1)
    np.testing.assert_allclose(np.linalg.det(Rn), 1.0, atol=1e-12)


def test_rotations_of_degenerate_covariances_come_from_libigl():
    # rank-1 and zero covariances do not fix a rotation: libigl's answer is kept
    A = np.zeros((3, 3, 3))
    A[:, :, 0] = np.outer([1.0, 0, 0], [0, 1.0, 0])
    A[:, :, 2] = np.eye(3)
    R0 = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, 3)).copy()
    np.testing.assert_array_equal(fit_rotations(A, R0)[:, :, :2], fit_rotations_igl(A)[:, :, :2])
    np.testing.assert_allclose(fit_rotations(A, R0)[:, :, 2], np.eye(3), atol=1e-15)


def test_local_step_rotations_match_libigl(tube):
    solver = _solver(tube)
    shape = solver.terms[0]
    X = solver.initial_guess()
    LX = shape.L @ X
    hint = fit_rotations_igl(shape.covariances(X + 0.01, shape.L @ (X + 0.01)))
    R = shape.rotations(X, LX, hint.transpose(2, 0, 1))
    # libigl on the stacked covariance in its own layout (S[a n + v, b] = A_v[b, a])
    S = shape.covariance @ X
    S += np.concatenate([shape.delta[:, [a]] * LX for a in range(3)])
    import igl

    ref = np.asarray(igl.fit_rotations(S, False)).reshape(3, -1, 3).transpose(1, 0, 2)
    # 1e-12: see test_rotations_match_libigl
    assert np.abs(R - ref).max() <= 1e-12


# -- terms: fast local steps equal the generic definition ----------------------------------


@pytest.mark.parametrize("term_index", [0, 1, 2])
def test_fast_local_step_equals_the_definition(tube, term_index):
    solver = _solver(tube)
    term = solver.terms[term_index]
    X = solver.initial_guess() + 0.05 * np.random.default_rng(2).normal(size=(solver.solver.n, 3))
    e_fast, g_fast = term.local(LocalState(X))
    state = LocalState(X)
    solver.terms[0].local(state)  # rotations, as in a real local step
    t = term.target(state)
    r = term.K @ X - t
    e = float(np.dot(term.weights, np.einsum("ij,ij->i", r, r)))
    g = term.K.T @ (term.weights[:, None] * r)
    # rounding only: the same sums in a different order
    assert e_fast == pytest.approx(e, rel=1e-12)
    assert np.abs(g_fast - g).max() <= 1e-10 * np.abs(g).max()
    assert isinstance(term, (ShapeTerm, StretchTerm, Term))


def test_quadratic_form_is_sum_of_KtWK(tube):
    solver = _solver(tube)
    Q = sum(sp.csr_matrix(t.K.T @ sp.diags(t.weights) @ t.K) for t in solver.terms)
    # rounding of the sparse products
    assert abs(Q - solver.solver.Q).max() <= 1e-12 * abs(Q).max()


def test_half_gradient_matches_finite_differences(patch):
    solver = _solver(patch)
    ls = solver.solver
    X = solver.initial_guess()
    X[ls.free] += 0.02 * np.random.default_rng(4).normal(size=(len(ls.free), 3))
    _, _, G = ls.local(X)
    rng = np.random.default_rng(5)
    D = np.zeros_like(X)
    D[ls.free] = rng.normal(size=(len(ls.free), 3))
    h = 1e-6
    fd = (ls.energy(X + h * D) - ls.energy(X - h * D)) / (2 * h)
    # the targets are closest points in fixed sets, so their own change does not
    # enter the gradient; central differences are accurate to O(h²) ~ 1e-7 relative
    assert 2.0 * np.vdot(G, D) == pytest.approx(fd, rel=1e-5)


# -- the iteration ----------------------------------------------------------------------------


@pytest.mark.parametrize("acceleration", [0, 10])
def test_energy_history_never_increases(tube, acceleration):
    solver = _solver(tube)
    res = solver.solve(acceleration=acceleration, max_iterations=150, energy_tolerance=1e-12)
    e = np.asarray(res.energy)
    # every plain step provably does not raise the energy, and the accelerated
    # one is accepted only if it lowers it; what remains is rounding of the
    # energy itself, a sum of ~10^4 squares (relative error ~1e-14), so 1e-12
    assert (np.diff(e) <= 1e-12 * e[:-1]).all()
    assert e[-1] < e[0]


def test_accelerated_run_reaches_the_plain_minimum(patch):
    plain = _solver(patch, acceleration=0, energy_tolerance=1e-13, max_iterations=20000).solve()
    fast = _solver(patch).solve()  # the defaults
    assert plain.converged and fast.converged
    # the bound: the default (accelerated) join stops within 1e-6 of the
    # energy that a long plain local/global run settles at
    assert abs(fast.energy[-1] - plain.energy[-1]) <= 1e-6 * plain.energy[-1]
    assert fast.iterations * 5 < plain.iterations
    # and at the same shape: 1e-4 of the guest size (measured 3e-6; an energy gap
    # of 1e-6 allows position differences of order sqrt(1e-6) along soft modes)
    assert np.abs(fast.guest.V - plain.guest.V).max() <= 1e-4 * _size(patch)


def test_iteration_statistics(patch):
    solver = _solver(patch)
    res = solver.solve()
    stats = solver.last_run.stats
    assert stats["back_solves"] >= res.iterations
    assert stats["local_steps"] == res.iterations + 1 + stats["rejected"]
    assert solver.last_run.timings["local"] > 0 and solver.last_run.timings["solve"] > 0


def test_max_iterations_is_respected(tube):
    solver = _solver(tube)
    for k in (1, 3):
        for acceleration in (0, 10):
            res = solver.solve(max_iterations=k, acceleration=acceleration)
            assert res.iterations == k and not res.converged
            assert res.stop_reason == "max_iterations"
            assert len(res.energy) == k + 1


def test_time_limit_is_respected(tube):
    solver = _solver(tube)
    res = solver.solve(time_limit=1e-9, energy_tolerance=1e-12)
    assert res.stop_reason == "time_limit" and not res.converged
    # the limit is checked after every iteration
    assert res.iterations == 1
    assert np.isfinite(res.guest.V).all()


def test_progress_is_called_after_every_iteration(patch):
    seen = []
    res = igljoin.join(
        patch.host, patch.guest, patch.host_curve, patch.guest_curve, progress=seen.append
    )
    assert [p.iteration for p in seen] == list(range(1, res.iterations + 1))
    # the energies reported are the ones the result records, exactly
    assert [p.energy for p in seen] == res.energy[1:]
    assert all(p.max_iterations == res.options.max_iterations for p in seen)
    elapsed = [p.elapsed for p in seen]
    assert elapsed == sorted(elapsed) and elapsed[0] >= 0.0
    # watching does not change the result
    quiet = igljoin.join(patch.host, patch.guest, patch.host_curve, patch.guest_curve)
    np.testing.assert_array_equal(res.guest.V, quiet.guest.V)


def test_progress_on_a_resolve_and_its_errors(patch):
    solver = _solver(patch)
    seen = []
    res = solver.solve(progress=seen.append, max_iterations=3)
    assert len(seen) == res.iterations == 3 and seen[-1].max_iterations == 3
    with pytest.raises(igljoin.OptionsError, match="must be a callable"):
        solver.solve(progress=3)


# -- convergence at a minimum of zero energy (and warm starts at a minimum) ----------------

# a guest already at its minimum must stop at once: the convergence test needs two
# iterations of history, a quasi-Newton start may need a few more; five is the bound
# the project promises
AT_ONCE = 5


def _real_cuts():
    """Two untouched pieces of real scans of different resolution (seeded, none picked by hand)."""
    pytest.importorskip("pymeshlab")  # ships the real test meshes
    from .cuts import cut_piece, sample_mesh_dir

    out = []
    for name, seed in (("bunny10k_textured.obj", 0), ("bunny.obj", 3)):
        mesh = igljoin.read_mesh(sample_mesh_dir() / name)
        rng = np.random.default_rng(seed)
        size = float(np.linalg.norm(np.ptp(mesh.V, axis=0)))
        cut = None
        while cut is None:
            cut = cut_piece(mesh, int(rng.integers(mesh.n_vertices)), size * rng.uniform(0.05, 0.2))
        out.append((name, cut))
    return out


@pytest.fixture(scope="module")
def real_cuts():
    return _real_cuts()


def _tube_continuation():
    """A straight artery cut across: the host below z = 0, the guest its exact continuation."""
    t = phantoms.artery_tube(4.0, 20.0, 48, 12)
    host = igljoin.Mesh(t.V * np.array([1.0, -1.0, -1.0]), t.F.copy(), name="host")
    guest = phantoms.artery_tube(4.0, 20.0, 48, 12, name="guest")
    return host, guest


@pytest.mark.parametrize("smooth", [False, True])
def test_untouched_real_piece_converges_at_once(real_cuts, smooth):
    # with the smooth term (band mode, the default) too: the crease these pieces meet
    # their hosts at is the fits' noise, which the band term keeps
    for name, cut in real_cuts:
        res = igljoin.join(cut.host, cut.piece, cut.host_curve, cut.piece_at_host, smooth=smooth)
        assert res.converged and res.stop_reason == "tolerance", name
        assert res.iterations <= AT_ONCE, (name, res.iterations)
        # it does not move: displacement at rounding level of the coordinates (1e-9 of the
        # piece's size is six orders above double rounding and far below any real motion)
        assert np.abs(res.guest.V[: cut.piece.n_vertices] - cut.piece.V).max() < 1e-9 * cut.diameter


def test_joined_tube_converges_at_once_with_and_without_the_smooth_term():
    host, guest = _tube_continuation()
    loop = phantoms.tube_end_loop(48)
    # the paper's smooth term is exactly zero on a smooth continuation, and so is the
    # band term (the default); the robust one is not (it moves this guest), and is
    # covered by the warm-start test below
    for options in ({"smooth": False}, {"smooth": True, "smooth_mode": "paper"}, {}):
        res = igljoin.join(host, guest, loop, loop, **options)
        assert res.converged and res.stop_reason == "tolerance", options
        assert res.iterations <= AT_ONCE, (options, res.iterations)
        # a zero-energy minimum: rounding only (the energy scale here is about 1e2)
        assert res.energy[-1] < 1e-20, options


@pytest.mark.parametrize("smooth", [False, True])
def test_a_start_at_the_minimum_converges_at_once(real_cuts, smooth):
    """Re-solving from a converged result stops at once, also at a minimum of non-zero energy."""
    from .cuts import rigid_motion

    host, guest = _tube_continuation()
    loop = phantoms.tube_end_loop(48)
    cases = [("tube", host, guest, loop, loop)]
    for i, (name, cut) in enumerate(real_cuts):
        R, t = rigid_motion(i, cut.diameter)
        moved = igljoin.Mesh(cut.piece.V @ R.T + t, cut.piece.F)
        cases.append((name, cut.host, moved, cut.host_curve, None))
    for name, h, g, hc, gc in cases:
        solver = igljoin.JoinSolver(h, g, hc, gc, smooth=smooth)
        first = solver.solve()
        assert first.converged, name
        again = solver.solve(start=first)
        assert again.converged and again.iterations <= AT_ONCE, (name, again.iterations)
        # same minimum: the first solve stopped within its tolerance (1e-7 relative over
        # five iterations), so the energies agree to well within 1e-6
        e1, e2 = first.energy[-1], again.energy[-1]
        assert e2 <= e1 * (1.0 + 1e-12) + 1e-20, name
        assert e1 - e2 <= 1e-6 * max(e1, 1e-300) + 1e-20, name


def test_bad_start_is_rejected(patch):
    solver = _solver(patch)
    n = len(solver.corr.V)
    for bad in (np.zeros((n - 1, 3)), np.full((n, 3), np.nan), "guest"):
        with pytest.raises(igljoin.OptionsError, match="start must be"):
            solver.solve(start=bad)


# -- where a re-solve starts ---------------------------------------------------------------


def _turned(points: np.ndarray, degrees: float, centre: np.ndarray | None = None) -> np.ndarray:
    """Points turned about the x axis through ``centre`` (default: their centroid; seam
    targets turned so are a slider's step)."""
    t = np.radians(degrees)
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(t), -np.sin(t)], [0.0, np.sin(t), np.cos(t)]])
    c = points.mean(axis=0) if centre is None else centre
    return (points - c) @ R.T + c


def test_a_rigid_move_of_the_seam_moves_the_start_rigidly(tube):
    """Seam targets turned as a whole: the re-solve starts from the earlier result turned."""
    solver = _solver(tube)
    first = solver.solve()
    T = _turned(first.seam_targets, 5.0)
    start = solver.warm_start(first, T)
    expected = _turned(first.guest.V, 5.0, centre=first.seam_targets.mean(axis=0))
    # the rigid fit of the seam recovers the turn to rounding, and the seam move left
    # to extend is rounding too: 1e-9 of the guest's size is far above both
    np.testing.assert_allclose(start, expected, atol=1e-9 * _size(tube))


def test_path_prediction_is_exact_for_a_linear_response():
    """Minima that depend linearly on their seam are predicted exactly from two of them."""
    rng = np.random.default_rng(3)
    n, seam = 40, np.arange(6)
    base, modes = rng.normal(size=(n, 3)), rng.normal(size=(2, n, 3))
    X = [base + a * modes[0] + b * modes[1] for a, b in ((0.0, 0.0), (1.0, 0.2), (0.3, 0.9))]
    want = base - 0.7 * modes[0] + 2.5 * modes[1]
    got = path_prediction(X[0], X[1:], seam, want[seam])
    # a least-squares fit of two coefficients and a sum of three terms: rounding only
    np.testing.assert_allclose(got, want, atol=1e-12 * np.abs(want).max())
    assert path_prediction(X[0], [], seam, want[seam]) is X[0]


def test_re_solves_along_a_path_start_near_the_next_minimum(patch):
    """Each re-solve from the one before: the earlier moves predict the next start."""
    solver = _solver(patch)
    results = [solver.solve()]
    T0 = results[0].seam_targets
    for k in (1, 2, 3):
        results.append(solver.solve(_turned(T0, k), start=results[-1]))
    T = _turned(T0, 4)

    def plain_start(X, targets, **options):
        return _solver(patch, **options).warm_start(X, targets)  # a solver that knows no path

    predicted = solver.warm_start(results[-1], T)
    plain = plain_start(results[-1], T)
    # a tight tolerance for the minimum itself; 5,000 bounds a failure (it converges first)
    tight = _solver(patch).solve(T, energy_tolerance=1e-12, max_iterations=5000)
    assert tight.converged
    e, e_min = solver.solver.energy, tight.energy[-1]
    # measured: the prediction leaves 2e-4 to 2e-3 of the plain start's excess energy
    # (first order: what is left is the response's curvature over the step, and each
    # earlier result's own convergence error), so 1e-2 leaves a margin of five and still
    # fails a start that predicts nothing
    assert e(predicted) - e_min < 1e-2 * (e(plain) - e_min)
    warm = solver.solve(T, start=results[-1])
    cold = solver.solve(T)
    assert warm.converged and warm.iterations < cold.iterations
    # the same minimum: both stop within their tolerance (1e-7 relative over five
    # iterations), so the energies agree to well within 1e-6 of the long run's
    for r in (warm, cold):
        assert abs(r.energy[-1] - e_min) <= 1e-6 * e_min
    # an iteration setting leaves the minima (and the path) as they are; a weight change
    # makes new ones (a new set-up) and forgets the path
    T5 = _turned(T0, 5)
    solver.update(energy_tolerance=1e-8)
    assert not np.array_equal(solver.warm_start(warm, T5), plain_start(warm, T5))
    solver.update(stretch_weight=2.0)
    assert np.array_equal(solver.warm_start(warm, T5), plain_start(warm, T5, stretch_weight=2.0))


def test_a_path_is_not_cut_by_solves_that_are_not_on_it(patch):
    """A cold solve between the steps of a path (as a comparison does) leaves the path."""
    solver = _solver(patch)
    first = solver.solve()
    T0 = first.seam_targets
    solver.solve(_turned(T0, 1))  # cold: a result of its own, not on the path
    step = solver.solve(_turned(T0, 1), start=first)
    solver.solve(_turned(T0, 2))
    T = _turned(T0, 2)
    fresh = _solver(patch)  # a solver that knows no path: rigid start and extension only
    fresh.solve()
    predicted, plain = solver.warm_start(step, T), fresh.warm_start(step, T)
    # a tight tolerance for the minimum itself; 5,000 bounds a failure (it converges first)
    tight = fresh.solve(T, energy_tolerance=1e-12, max_iterations=5000)
    assert tight.converged
    e, e_min = solver.solver.energy, tight.energy[-1]
    # as in the test above: the prediction leaves 2e-4 to 2e-3 of the plain start's
    # excess energy, so 1e-2 fails a start that predicts nothing
    assert e(predicted) - e_min < 1e-2 * (e(plain) - e_min)


def _first_slider_step(patch, monkeypatch, spy):
    """A solver whose runs go through ``spy``, solved cold and then warm after a 1° turn of
    its targets (from a cold result: no path yet); the solver, the first targets, the step."""
    from igljoin.solve import LocalGlobalSolver

    monkeypatch.setattr(LocalGlobalSolver, "run", spy)
    solver = _solver(patch)
    first = solver.solve()
    T0 = first.seam_targets
    return solver, T0, solver.solve(_turned(T0, 1), start=first)


def test_a_re_solve_along_a_path_starts_with_the_quasi_newton_pairs_before(patch, monkeypatch):
    """The second step of a path starts with the first step's pairs; they are copied."""
    from igljoin.solve import LocalGlobalSolver

    given = []
    run = LocalGlobalSolver.run

    def spy(self, X0, bc, **kw):
        memory = kw.get("memory")
        given.append(None if memory is None else (memory.size, memory.S.copy()))
        out = run(self, X0, bc, **kw)
        if memory is not None:  # the run copied the pairs and left them as they were
            assert np.array_equal(memory.S, given[-1][1])
        return out

    solver, T0, step1 = _first_slider_step(patch, monkeypatch, spy)
    pairs = solver.last_run.memory
    step2 = solver.solve(_turned(T0, 2), start=step1)
    step3 = solver.solve(_turned(T0, 3), start=step2)
    again = solver.solve(_turned(T0, 3), start=step2)
    assert given[0] is None and given[1] is None
    assert given[2][0] == pairs.size > 0
    assert np.array_equal(given[2][1], pairs.S)
    # the newest step again from the result before it: the same pairs (copied, not used
    # up), the same result, to the bit
    assert given[3] is not None and step3.converged
    assert given[4][0] == given[3][0] and np.array_equal(given[4][1], given[3][1])
    assert np.array_equal(step3.guest.V, again.guest.V)
    # the plain iteration holds no pairs and keeps none
    # 3,000: the plain iteration needs several hundred here; the cap only bounds a failure
    plain = solver.solve(_turned(T0, 3), start=step2, acceleration=0, max_iterations=3000)
    assert plain.converged and solver.last_run.memory is None


def test_a_re_solve_along_a_path_starts_its_rotation_fit_from_the_step_before(patch, monkeypatch):
    """The second step of a path fits its first rotations from the first step's last ones,
    turned as its seam turns onto the new targets; it ends where a fit from no hint ends."""
    from igljoin.solve import LocalGlobalSolver

    given, ended = [], []
    run = LocalGlobalSolver.run

    def spy(self, X0, bc, **kw):
        given.append(kw.get("rotations"))
        out = run(self, X0, bc, **kw)
        ended.append(out.rotations)
        return out

    solver, T0, step1 = _first_slider_step(patch, monkeypatch, spy)
    T2 = _turned(T0, 2)
    step2 = solver.solve(T2, start=step1)
    assert given[0] is None and given[1] is None
    n = len(solver.corr.V)
    assert ended[1].shape == (n, 3, 3) and given[2].shape == (n, 3, 3)
    # the hint is the step before's last rotations, turned as the seam turns from the step
    # before onto the new targets
    seam = solver.corr.seam
    turn = igljoin.correspond.rigid_fit(step1.guest.V[seam], T2)[0]
    assert np.array_equal(given[2], np.matmul(turn, ended[1]))
    # a turn of about the slider's step (1 degree), not of nothing
    angle = np.degrees(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0)))
    assert 0.5 < angle < 1.5  # the seam's fit turns with the slider's 1 degree, within half
    X0 = solver._warm_start(step1.guest.V, T2, solver._kept_at(step1.guest.V))
    # the same step's run without the hint: the same iterations, the same minimum to the
    # rounding the rotation fit leaves (Newton stops at a step of 1e-7 rad, so each
    # rotation is exact to about 1e-14; the energies agree to 1e-10 relative)
    ls, opt = solver.solver, solver.options
    kw = dict(
        tolerance=opt.energy_tolerance,
        scale=solver.guest_mean_edge,
        acceleration=opt.acceleration,
        memory=solver._kept[-2].memory,
    )
    plain = run(ls, X0, T2, **kw)
    assert plain.iterations == step2.iterations
    assert abs(plain.energy[-1] - step2.energy[-1]) <= 1e-10 * plain.energy[-1]


def test_pairs_larger_than_the_limit_are_not_kept(patch, monkeypatch):
    """Above ``PAIRS_MAX_BYTES`` a path's re-solves start without pairs (and hold none)."""
    join_module = importlib.import_module("igljoin.join")  # igljoin.join is the function
    solver = _solver(patch)
    first = solver.solve()
    T0 = first.seam_targets
    step1 = solver.solve(_turned(T0, 1), start=first)
    size = solver.last_run.memory.S.nbytes + solver.last_run.memory.Y.nbytes
    monkeypatch.setattr(join_module, "PAIRS_MAX_BYTES", size - 1)
    step2 = solver.solve(_turned(T0, 2), start=step1)
    assert step2.converged and np.array_equal(solver._kept[-1].X, step2.guest.V)
    assert solver._kept[-1].memory is None and solver.last_run.memory is None
    # the rotations (9n' floats, far fewer than the pairs) are kept all the same
    assert solver._kept[-1].rotations is not None
    monkeypatch.setattr(join_module, "PAIRS_MAX_BYTES", size)
    solver.solve(_turned(T0, 3), start=step2)
    assert solver._kept[-1].memory is not None


def test_a_run_started_with_pairs_reaches_the_same_minimum(patch):
    """``run(memory=...)``: other steps, the same minimum; pairs of another size are ignored."""
    solver = _solver(patch)
    first = solver.solve()
    ls, opt = solver.solver, solver.options
    T = _turned(first.seam_targets, 1)
    X0 = solver.warm_start(first, T)
    kw = dict(tolerance=opt.energy_tolerance, scale=solver.guest_mean_edge, acceleration=10)
    pairs = solver.last_run.memory
    plain = ls.run(X0, T, **kw)
    carried = ls.run(X0, T, memory=pairs, **kw)
    other = ls.run(X0, T, memory=pairs, **{**kw, "acceleration": 5})
    assert plain.converged and carried.converged
    assert carried.energy[1] != plain.energy[1]  # the first step used the pairs
    # both stop within their tolerance (1e-7 relative over five iterations): 1e-6 apart
    assert abs(carried.energy[-1] - plain.energy[-1]) <= 1e-6 * plain.energy[-1]
    # pairs of 10 do not fit a run of 5: it starts without any, as a run given none
    assert other.energy == ls.run(X0, T, **{**kw, "acceleration": 5}).energy


def test_the_floor_is_made_only_where_it_can_decide(tube):
    """The floor test answers as ``e <= energy_floor`` and makes the floor only near it."""
    from igljoin.solve import _FloorTest

    solver = _solver(tube)
    ls, X = solver.solver, solver.initial_guess()
    tol = solver.options.energy_tolerance
    floor = ls.energy_floor(X, tol)
    test = _FloorTest(ls, X, tol)
    assert floor <= test.bound < np.inf
    for e in (0.0, 0.5 * floor, floor, np.nextafter(floor, np.inf), 2.0 * floor, 10 * test.bound):
        assert _FloorTest(ls, X, tol).reached(e) == (e <= floor), e
    # an energy above the bound (every real join's) never makes the floor
    test.reached(2.0 * test.bound)
    assert test.floor is None
    test.reached(floor)
    assert test.floor == floor


# -- reuse of the factorization across solves ----------------------------------------------


def test_resolves_reuse_the_factorization(patch):
    """New targets, iteration settings or a warm start never refactor; a weight change does."""
    solver = _solver(patch, max_iterations=50)
    first = solver.solve()
    # the plain local/global step needs Q itself (P is scaled): made once, on first use
    solver.solve(acceleration=0, max_iterations=3)
    made = linsolve.FixedQuadratic.made
    rng = np.random.default_rng(7)
    # a seam target change of 1 % of the guest's size, the slider's kind of change
    targets = first.seam_targets + 0.01 * _size(patch) * rng.normal(size=first.seam_targets.shape)
    runs = [
        solver.solve(targets),
        solver.solve(targets, start=first),
        solver.solve(energy_tolerance=1e-9, max_iterations=400),
        solver.solve(acceleration=3, time_limit=30.0),
        solver.solve(acceleration=0, max_iterations=5),
        solver.solve(initial_guess="rigid"),
    ]
    assert linsolve.FixedQuadratic.made == made
    assert solver.factorizations == 1
    assert all(r.iterations >= 1 for r in runs)
    # the re-solve with new targets reaches them (hard constraints)
    np.testing.assert_allclose(runs[0].guest.V[runs[0].seam], targets, atol=1e-9 * _size(patch))
    solver.solve(stretch_weight=2.0)
    assert linsolve.FixedQuadratic.made > made and solver.factorizations == 2


# -- the quasi-Newton memory ---------------------------------------------------------------


def _two_loop(g, pairs, scale):
    """The L-BFGS two-loop recursion by its definition (initial inverse Hessian ``scale``)."""
    q = g.reshape(-1).copy()
    alphas = []
    for s, y in reversed(pairs):
        a = float(np.dot(s, q)) / float(np.dot(s, y))
        alphas.append(a)
        q -= a * y
    z = scale * q
    for (s, y), a in zip(pairs, reversed(alphas)):
        b = float(np.dot(y, z)) / float(np.dot(s, y))
        z += (a - b) * s
    return z.reshape(g.shape)


def test_quasi_newton_memory_keeps_the_last_pairs_of_positive_curvature():
    from igljoin.solve import QuasiNewtonMemory

    rng = np.random.default_rng(0)
    shape = (1001, 3)  # an odd size: the kernels' unrolled loops have a remainder
    memory = QuasiNewtonMemory(3, shape)
    kept = []
    for k in range(6):
        x, g = rng.normal(size=shape), rng.normal(size=shape)
        s = rng.normal(size=shape)
        # every third pair has negative curvature and must be refused
        y = (-1.0 if k % 3 == 2 else 1.0) * s + 0.1 * rng.normal(size=shape)
        memory.push(x + s, x, g + y, g)
        if k % 3 != 2:
            kept.append((s.reshape(-1), y.reshape(-1)))
    kept = kept[-3:]
    assert memory.size == 3
    g = rng.normal(size=shape)
    z = memory.apply(g, lambda v: 0.5 * v)
    ref = _two_loop(g, kept, 0.5)
    # the same sums in another order over 3003 entries: rounding only
    assert np.abs(z - ref).max() <= 1e-12 * np.abs(ref).max()
    memory.clear()
    assert memory.size == 0
    assert np.array_equal(memory.apply(g, lambda v: 0.5 * v), 0.5 * g)


def test_dot_kernel_is_the_dot_product():
    from igljoin import kernels

    rng = np.random.default_rng(1)
    for n in (0, 1, 7, 30001):
        a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        ref = float(np.dot(a.reshape(-1), b.reshape(-1)))
        # partial sums in another order: rounding of a sum of 3n products of size ~1
        assert kernels.dot(a, b) == pytest.approx(ref, rel=1e-12, abs=1e-12 * np.sqrt(3 * n + 1))


def test_row_and_step_kernels_are_their_numpy_expressions():
    """The iteration's compiled scatter, step and largest move: numpy's floats, to the bit."""
    from igljoin import kernels

    rng = np.random.default_rng(2)
    n = 1001
    rows = rng.permutation(n)
    free, fixed = np.sort(rows[:900]), np.sort(rows[900:])
    x, bc = rng.normal(size=(900, 3)), rng.normal(size=(101, 3))
    X = np.empty((n, 3))
    X[free], X[fixed] = x, bc
    assert np.array_equal(kernels.join_rows(n, free, x, fixed, bc), X)
    d = rng.normal(size=(900, 3))
    for t in (1.0, 0.5, 0.1234567):
        assert np.array_equal(kernels.step(x, t, d), x + t * d)
    # any memory order: a Fortran-ordered x, a strided d
    xf, ds = np.asfortranarray(x), np.repeat(d, 2, axis=0)[::2]
    assert np.array_equal(kernels.step(xf, 0.3, ds), x + 0.3 * d)
    assert kernels.abs_max(d) == np.abs(d).max()
    d[5, 1] = np.nan
    assert np.isnan(kernels.abs_max(d)) and np.isnan(np.abs(d).max())


def test_a_quasi_newton_memory_copy_is_independent():
    from igljoin.solve import QuasiNewtonMemory

    rng = np.random.default_rng(3)
    shape = (50, 3)
    memory = QuasiNewtonMemory(2, shape)
    x, g, s = (rng.normal(size=shape) for _ in range(3))
    memory.push(x + s, x, g + s, g)
    other = memory.copy()
    assert other.size == memory.size == 1 and other.m == memory.m
    g2 = rng.normal(size=shape)
    assert np.array_equal(other.apply(g2, lambda v: v), memory.apply(g2, lambda v: v))
    other.push(x + 2 * s, x, g + 3 * s, g)
    other.clear()
    assert memory.size == 1 and other.size == 0
    # every attribute copied, none shared (a field added later is copied too): the
    # arrays and lists are new objects, everything else an immutable value (a dict or
    # another mutable field added later fails here until copy() copies it)
    assert vars(other).keys() == vars(memory).keys()
    for key, value in vars(memory).items():
        if isinstance(value, (np.ndarray, list)):
            assert vars(other)[key] is not value, key
        else:
            assert isinstance(value, (int, float, bool, str, tuple, type(None))), key


# -- a refused change leaves the solver as it was --------------------------------------------


def test_a_refused_set_up_leaves_the_solver_as_it_was(patch, monkeypatch):
    from igljoin import bandfit

    solver = _solver(patch)
    first = solver.solve()
    corr, factor, made = solver.corr, solver.solver, solver.factorizations
    # the next set-up's band fits are refused (a stand-in for a band too large for its fit)
    monkeypatch.setattr(bandfit, "MAX_FIT_ENTRIES", 10)
    with pytest.raises(igljoin.OptionsError, match="MAX_FIT_ENTRIES"):
        solver.update(snap_fraction=0.2)
    monkeypatch.undo()
    assert solver.options.snap_fraction == first.options.snap_fraction
    assert solver.corr is corr and solver.solver is factor and solver.factorizations == made
    again = solver.solve()
    # the same set-up and options: the same iterations and energy, to the bit
    assert again.iterations == first.iterations and again.energy[-1] == first.energy[-1]


def test_a_refused_solve_takes_back_its_option_changes(patch, monkeypatch):
    from igljoin import twolevel

    solver = _solver(patch)
    first = solver.solve()
    monkeypatch.setattr(twolevel, "MAX_MODEL_ENTRIES", 100)
    with pytest.raises(igljoin.OptionsError, match="MAX_MODEL_ENTRIES"):
        solver.solve(preconditioner="two-level")
    # the refused model is not kept for the next solve: asked again, it is refused again
    # (a kept one, its clusters already made, would be built past the limit)
    with pytest.raises(igljoin.OptionsError, match="MAX_MODEL_ENTRIES"):
        solver.solve(preconditioner="two-level")
    with pytest.raises(igljoin.OptionsError, match="targets must be"):
        solver.solve(np.zeros((2, 3)), energy_tolerance=1e-3)
    monkeypatch.undo()
    assert solver.options == first.options
    again = solver.solve()
    assert again.iterations == first.iterations and again.energy[-1] == first.energy[-1]
