"""The compiled local steps (igljoin.kernels) equal the numpy reference path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import igljoin
from igljoin import kernels, phantoms
from igljoin.rotations import fit_rotations_igl
from igljoin.terms import LocalState, ShapeTerm, SmoothJoinTerm, StretchTerm


@pytest.fixture(scope="module")
def tube():
    """The paper's end-to-end sample at half resolution (about 600 guest vertices)."""
    return phantoms.paper_sample("end_to_end", "longer", resolution=0.5)


def _solver(s, **options):
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)


def _both(term, X, hint=None, rotations=None):
    """(energy, half-gradient, rotations) by the compiled and by the numpy path."""
    out = []
    for compiled in (True, False):
        term.compiled = compiled
        state = LocalState(np.ascontiguousarray(X), hint=hint, rotations=rotations)
        e, g = term.local(state)
        out.append((e, g, state.rotations))
    term.compiled = True
    return out


def _perturbed(solver, scale, seed):
    X = solver.initial_guess()
    rng = np.random.default_rng(seed)
    return X + scale * solver.guest_mean_edge * rng.normal(size=X.shape)


# rounding only: the same sums in a different order; energies are sums of ~10^4
# squares and gradients sums of a few dozen products, so 1e-12 / 1e-10 relative
_E_REL = 1e-12
_G_REL = 1e-10


@pytest.mark.parametrize("with_hint", [False, True])
def test_shape_kernel_equals_numpy(tube, with_hint):
    solver = _solver(tube)
    shape = solver.terms[0]
    assert isinstance(shape, ShapeTerm) and shape.compiled
    X = _perturbed(solver, 0.3, 1)
    hint = None
    if with_hint:
        # rotations of a nearby iterate, as the iteration passes them
        near = LocalState(_perturbed(solver, 0.3, 2))
        shape.local(near)
        hint = near.rotations
    (ek, gk, Rk), (en, gn, Rn) = _both(shape, X, hint)
    assert ek == pytest.approx(en, rel=_E_REL)
    assert np.abs(gk - gn).max() <= _G_REL * np.abs(gn).max()
    # both are the exact maximisers (libigl's SVD fit to rounding), see test_solve
    assert np.abs(Rk - Rn).max() <= 1e-12


def test_shape_kernel_rotations_are_libigls(tube):
    solver = _solver(tube)
    shape = solver.terms[0]
    X = _perturbed(solver, 0.5, 3)
    state = LocalState(X)
    shape.local(state)
    ref = fit_rotations_igl(shape.covariances(X, shape.L @ X)).transpose(2, 0, 1)
    # 1e-12: Newton settles to rounding (see igljoin.rotations.STEP_TOLERANCE)
    assert np.abs(state.rotations - ref).max() <= 1e-12
    det = np.linalg.det(state.rotations)
    # proper rotations to rounding
    assert np.abs(det - 1.0).max() <= 1e-12


def test_shape_kernel_survives_a_hint_half_a_turn_away(tube):
    """A hint where Newton cannot settle (a saddle) falls back to the SVD."""
    solver = _solver(tube)
    shape = solver.terms[0]
    X = _perturbed(solver, 0.2, 4)
    flip = Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_matrix()
    state = LocalState(X)
    shape.local(state)
    hint = np.einsum("ij,njk->nik", flip, state.rotations)
    (ek, gk, Rk), (en, gn, Rn) = _both(shape, X, hint)
    # 1e-12: both end at libigl's global maximiser (see above)
    assert np.abs(Rk - state.rotations).max() <= 1e-12
    assert ek == pytest.approx(en, rel=_E_REL)


def test_stretch_kernel_equals_numpy_with_a_collapsed_edge(tube):
    solver = _solver(tube)
    stretch = solver.terms[1]
    assert isinstance(stretch, StretchTerm) and stretch.compiled
    X = _perturbed(solver, 0.2, 5)
    i, j = stretch.E[7]
    X[j] = X[i]  # edge 7 has zero length: its target is the rotated rest edge
    shape_state = LocalState(X)
    solver.terms[0].local(shape_state)
    for rotations in (None, shape_state.rotations):
        (ek, gk, _), (en, gn, _) = _both(stretch, X, rotations=rotations)
        assert ek == pytest.approx(en, rel=_E_REL)
        assert np.abs(gk - gn).max() <= _G_REL * np.abs(gn).max()


@pytest.mark.parametrize(
    "options",
    [
        {"smooth_mode": "robust"},
        {"smooth_mode": "paper"},
        {"smooth_mode": "robust", "smooth_keep_deg": 5.0},
    ],
    ids=["robust", "paper", "wedge"],
)
def test_smooth_kernel_equals_numpy(tube, options):
    solver = _solver(tube, **options)
    smooth = solver.terms[2]
    assert isinstance(smooth, SmoothJoinTerm) and smooth.compiled
    # large perturbation: some edges fold back into the host, some leave the wedge
    X = _perturbed(solver, 1.0, 6)
    (ek, gk, _), (en, gn, _) = _both(smooth, X)
    assert ek == pytest.approx(en, rel=_E_REL)
    assert np.abs(gk - gn).max() <= _G_REL * np.abs(gn).max()


@pytest.mark.parametrize("keep", [None, 5.0], ids=["half-plane", "wedge"])
def test_band_kernel_equals_numpy(tube, keep):
    solver = _solver(tube, smooth_mode="band", smooth_keep_deg=keep)
    bands = [t for t in solver.terms if isinstance(t, SmoothJoinTerm)]
    assert bands and all(t.mode == "band" and t.compiled for t in bands)
    # large perturbation: some rows fold back into the host, some leave the wedge
    X = _perturbed(solver, 1.0, 7)
    for band in bands:
        (ek, gk, _), (en, gn, _) = _both(band, X)
        assert ek == pytest.approx(en, rel=_E_REL)
        assert np.abs(gk - gn).max() <= _G_REL * np.abs(gn).max()


def test_band_kernel_reads_the_fits_own_columns(tube):
    solver = _solver(tube, smooth_mode="band")
    band = next(t for t in solver.terms if isinstance(t, SmoothJoinTerm))
    # the columns the kernel reads are K's, not a copy of them in another integer type
    assert np.shares_memory(band._Ki, band.K.indices) and band._Ki.dtype == np.int32
    X = _perturbed(solver, 1.0, 7)
    # and give what int64 columns gave, to the bit
    out = []
    for Ki in (band._Ki, band._Ki.astype(np.int64)):
        G = np.zeros_like(X)
        args = (band._Kp, Ki, band._Kx, band.normal, band.outward, band.weights, band._tol_c)
        out.append((kernels.band_local(X, *args, G), G))
    assert out[0][0] == out[1][0] and np.array_equal(out[0][1], out[1][1])


def test_shape_term_holds_no_copy_the_compiled_step_does_not_read(tube):
    solver = _solver(tube)
    shape = solver.terms[0]
    assert isinstance(shape, ShapeTerm) and shape.compiled and shape.rotation_aware
    solver.solve()
    # the numpy step's transposed copies were never made, and the Laplacian's columns
    # are L's own
    assert "_deltaT" not in vars(shape) and "_e0T" not in vars(shape)
    assert np.shares_memory(shape._Li, shape.L.indices)
    # the numpy step makes them where it first reads them
    _both(shape, _perturbed(solver, 0.1, 3))
    assert np.array_equal(shape._deltaT, shape.delta.T) and shape._deltaT.flags.c_contiguous
    assert np.array_equal(shape._e0T, shape.rest_edges.T) and shape._e0T.flags.c_contiguous


def test_numpy_path_gives_the_same_join(tube):
    """Terms switched to their numpy reference path (``compiled=False``) give the same join."""
    reference = _solver(tube)
    for term in reference.terms:
        term.compiled = False
    ref = reference.solve()
    res = igljoin.join(tube.host, tube.guest, tube.host_curve, tube.guest_curve)
    assert all(isinstance(t, ShapeTerm | StretchTerm | SmoothJoinTerm) for t in reference.terms)
    assert not any(t.compiled for t in reference.terms)
    # both paths compute the same numbers up to summation order (~1e-13 relative per
    # step); over a converging run that can shift the stopping iteration by a few
    assert abs(ref.iterations - res.iterations) <= 3
    # and they stop at the same minimum: within the convergence tolerance (1e-7)
    assert ref.energy[-1] == pytest.approx(res.energy[-1], rel=1e-6)
    size = float(np.linalg.norm(np.ptp(tube.guest.V, axis=0)))
    # soft modes allow position differences of order sqrt(1e-7) of the size
    assert np.abs(ref.guest.V - res.guest.V).max() <= 1e-3 * size


def test_terms_are_compiled_by_default_and_on_request(tube):
    solver = _solver(tube, smooth_mode="robust")
    assert [t.compiled for t in solver.terms] == [True, True, True]
    c = solver.corr
    shape = ShapeTerm(c.V, c.F, compiled=False)
    stretch = StretchTerm(c.V, shape.E, np.ones(len(shape.E)), compiled=False)
    assert not shape.compiled and not stretch.compiled


def _rotation_fit_cases(seed):
    """Covariances and hints of every kind the rotation fit meets, shape (n, 3, 3) each.

    150 vertices (two blocks and a part of one): hints at their rotation, near
    it (two Newton steps), 0.8 rad away (more steps), 2.5 rad away (Newton
    breaks off), half a turn away (a saddle), and covariances of rank 2, and
    of rank 1 or zero, shuffled so that every block mixes them.
    """
    rng = np.random.default_rng(seed)
    n = 150
    target = Rotation.random(n, random_state=seed).as_matrix()
    A = target @ (np.eye(3) * rng.uniform(0.5, 3.0, size=(n, 1, 3)))
    kind = rng.permutation(np.arange(n) % 7)
    turn = np.array([0.0, 1e-3, 0.8, 2.5, 0.0, 0.0, 0.0])[kind]
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    hint = Rotation.from_rotvec(turn[:, None] * axis).as_matrix() @ target
    half = kind == 4
    hint[half] = Rotation.from_rotvec(np.pi * axis[half]).as_matrix() @ target[half]
    A[kind == 5] = A[kind == 5] @ np.diag([1.0, 1.0, 0.0])
    A[kind == 6] = np.outer([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]) if seed % 2 else 0.0
    return np.ascontiguousarray(A), np.ascontiguousarray(hint)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_block_rotation_fit_is_the_per_vertex_newton(seed):
    """The fit a block at a time gives each vertex exactly its own Newton iteration's result."""
    A, hint = _rotation_fit_cases(seed)
    n = len(A)
    R = np.empty_like(A)
    failed = np.zeros(n, dtype=bool)
    any_failed = kernels._fit_rotations(A, hint, R, failed)
    ref = hint.copy()
    settled = np.array(
        [kernels._newton_rotation(A[v], ref[v], kernels._MAX_STEPS) for v in range(n)]
    )
    # the same operations in the same order: equal to the last bit, failures included
    assert np.array_equal(R, ref)
    assert np.array_equal(failed, ~settled)
    assert any_failed == (not settled.all())
    # the cases reach both outcomes, and some vertices settle only after three steps
    assert settled.any() and not settled.all()
    short = hint.copy()
    assert any(settled[v] and not kernels._newton_rotation(A[v], short[v], 3) for v in range(n))


def test_stretch_term_reads_the_edge_vectors_the_shape_term_left(tube, monkeypatch):
    """The shape term's step leaves ``D X`` for the stretch term; both give what they give alone."""
    solver = _solver(tube)
    shape, stretch = solver.terms[0], solver.terms[1]
    assert shape.E is stretch.E  # the cache is keyed by the edge array: one array for both
    assert shape.compiled  # the compiled step is the one that leaves the edge vectors
    X = _perturbed(solver, 0.3, 8)
    shared = LocalState(X)
    shape.local_into(shared, np.zeros_like(X))
    left = [v for k, v in shared.cache.items() if isinstance(k, tuple) and k[0] == "edges"]
    assert len(left) == 1 and np.array_equal(left[0], kernels.edge_vectors(X, stretch.E))
    G_shared = np.zeros_like(X)
    computed = kernels.edge_vectors
    with monkeypatch.context() as m:

        def refuse(*args):
            raise AssertionError("the stretch term computed the edge vectors again")

        m.setattr(kernels, "edge_vectors", refuse)
        e_shared = stretch.local_into(shared, G_shared)
    assert kernels.edge_vectors is computed
    alone = LocalState(X, rotations=shared.rotations)
    G_alone = np.zeros_like(X)
    e_alone = stretch.local_into(alone, G_alone)
    # the same differences of the same positions: equal to the last bit
    assert e_shared == e_alone and np.array_equal(G_shared, G_alone)


def test_row_sums_and_the_gram_bound():
    """``abs_row_sums`` is numpy's sum of the stored entries' magnitudes, row by row, to the
    bit; ``gram_row_bound`` bounds every row's absolute sum of ``Kᵀ diag(w) K``."""
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    K = sp.random(40, 25, density=0.2, format="csr", random_state=rng)
    K.data -= 0.5  # entries of both signs
    w = rng.uniform(0.0, 2.0, size=40)
    w[::7] = 0.0  # rows of zero weight, as the band rows have
    rows = np.repeat(np.arange(40), np.diff(K.indptr))
    expected = np.bincount(rows, weights=np.abs(K.data), minlength=40)
    assert np.array_equal(kernels.abs_row_sums(K.indptr, K.data), expected)
    gram = (K.T @ sp.diags(w) @ K).toarray()
    bound = kernels.gram_row_bound(K.indptr, K.indices, K.data, w, 25)
    # the bound sums the same products without their signs' cancellation: 1e-12 relative
    # covers the two sums' different order where nothing cancels
    assert np.abs(gram).sum(axis=1).max() <= bound * (1.0 + 1e-12)
    # λ_max is at most the largest absolute row sum, itself below the bound (above)
    assert np.linalg.eigvalsh(gram).max() <= bound * (1.0 + 1e-12)
    assert kernels.gram_row_bound(K.indptr, K.indices, K.data, np.zeros(40), 25) == 0.0
