"""The upper triangle handed to Pardiso: placed directly for an augmented system."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import linsolve


def _parts(seed: int, m: int = 60, r: int = 7, diagonal: bool = True):
    rng = np.random.default_rng(seed)
    B = sp.random(m, m, density=0.08, random_state=rng, format="csr")
    S = sp.csr_matrix(B + B.T + (sp.eye(m) * 4.0 if diagonal else 0))
    K = sp.random(r, m, density=0.3, random_state=rng, format="csr")
    d = -rng.uniform(0.5, 2.0, r)
    A = sp.bmat([[S, K.T], [K, sp.diags(d)]], format="csr")
    return S, sp.csr_matrix(K.T), d, A


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_placed_triangle_is_the_assembled_matrix_cut(seed):
    S, Kt, d, A = _parts(seed)
    U = linsolve.augmented_upper(S, Kt, d)
    ref = linsolve._upper(A)
    assert linsolve._is_upper(U) and linsolve._is_upper(ref)
    # the same arrays, not only the same matrix: Pardiso factors them as they are
    np.testing.assert_array_equal(U.indptr, ref.indptr)
    np.testing.assert_array_equal(U.indices, ref.indices)
    np.testing.assert_array_equal(U.data, ref.data)
    # the index type LP64 Pardiso reads, so that it takes the arrays without a copy
    assert U.indptr.dtype == U.indices.dtype == np.int32


def test_unsorted_parts_are_placed_in_order():
    S, Kt, d, A = _parts(3)

    # the same matrices with each row's entries reversed
    def reversed_rows(M):
        data, indices = M.data.copy(), M.indices.copy()
        for i in range(M.shape[0]):
            a, b = M.indptr[i], M.indptr[i + 1]
            data[a:b], indices[a:b] = data[a:b][::-1], indices[a:b][::-1]
        return sp.csr_matrix((data, indices, M.indptr.copy()), shape=M.shape)

    U = linsolve.augmented_upper(reversed_rows(S), reversed_rows(Kt), d)
    ref = linsolve._upper(A)
    np.testing.assert_array_equal(U.indices, ref.indices)
    np.testing.assert_array_equal(U.data, ref.data)


def test_a_triangle_without_a_stored_diagonal_is_not_taken_as_placed():
    # a zero diagonal entry of S is not stored: Pardiso needs it, so the triangle is
    # converted (the zero added) before it is factored
    S, Kt, d, A = _parts(4, diagonal=False)
    missing = np.flatnonzero(S.diagonal() == 0)
    assert missing.size
    U = linsolve.augmented_upper(S, Kt, d)
    assert not linsolve._is_upper(U)
    ref = linsolve._upper(A)
    converted = linsolve._upper(U)
    np.testing.assert_array_equal(converted.indices, ref.indices)
    np.testing.assert_array_equal(converted.data, ref.data)


@pytest.mark.skipif(
    "pardiso" not in linsolve.available_backends(), reason="mkl (igljoin[pardiso]) missing"
)
def test_pardiso_factors_the_placed_triangle_as_the_assembled_matrix():
    S, Kt, d, A = _parts(5)
    b = np.random.default_rng(6).standard_normal((A.shape[0], 3))
    placed = linsolve._Pardiso(linsolve.augmented_upper(S, Kt, d), indefinite=True)
    assembled = linsolve._Pardiso(A, indefinite=True)
    # the same arrays factored: the same floats
    np.testing.assert_array_equal(placed.solve(b), assembled.solve(b))
    # and a solve of the system (its LDLᵀ residual at rounding, 1e-10 far above it for
    # this well-conditioned matrix)
    assert np.linalg.norm(A @ placed.solve(b) - b) <= 1e-10 * np.linalg.norm(b)


@pytest.mark.skipif(
    "pardiso" not in linsolve.available_backends(), reason="mkl (igljoin[pardiso]) missing"
)
def test_a_system_past_pardisos_32_bit_indices_is_refused(monkeypatch):
    # the limit lowered to stand in for a system of more than 2**31 entries (tens of GB)
    S, Kt, d, A = _parts(8)
    U = linsolve.augmented_upper(S, Kt, d)
    monkeypatch.setattr(linsolve, "_LP64_MAX", U.nnz - 1)
    with pytest.raises(igljoin.SolveError, match="32-bit.*linear_solver='cholespy'"):
        linsolve._Pardiso(U, indefinite=True)
    monkeypatch.setattr(linsolve, "_LP64_MAX", U.nnz)
    assert linsolve._Pardiso(U, indefinite=True).n == U.shape[0]
