"""Prefactored solves of a sparse quadratic form with fixed rows (linear-solver backends).

The global step of the join minimises ``½ xᵀ Q x − xᵀ B`` with the rows
``fixed`` held at ``bc``: ``Q_ff x_f = B_f − Q_fb bc``. ``Q`` never changes
during a solve, so it is factored once and every iteration is a
back-substitution. Two backends give the same answer (to rounding):

* ``"igl"`` — libigl's ``min_quad_with_fixed_precompute`` / ``_solve``;
  always available (libigl is a dependency).
* ``"cholespy"`` — a sparse (simplicial) Cholesky of ``Q_ff`` (the
  ``igljoin[fast]`` extra); its back-substitutions are several times faster
  (0.2 ms for a paper-sized guest, the fastest of the backends measured in
  docs/benchmarks.md).

``"auto"`` picks cholespy when it is installed and libigl otherwise.
"""

from __future__ import annotations

import importlib.util

import igl
import numpy as np
import scipy.sparse as sp

from .errors import MissingExtraError, OptionsError, SolveError

__all__ = ["BACKENDS", "FixedQuadratic", "available_backends", "resolve_backend"]

#: Names accepted by ``linear_solver``.
BACKENDS = ("auto", "igl", "cholespy")

_NOT_FACTORED = (
    "the deformation system could not be factored (a part of the guest is not held by any "
    "term); check that every guest component touches the seam"
)


def available_backends() -> list[str]:
    """Backends that can run here (``"igl"`` always; ``"cholespy"`` if installed)."""
    out = ["igl"]
    if importlib.util.find_spec("cholespy") is not None:
        out.append("cholespy")
    return out


def resolve_backend(name: str) -> str:
    """The concrete backend for ``name`` (``"auto"`` → cholespy if installed, else igl).

    Raises
    ------
    OptionsError
        Unknown name.
    MissingExtraError
        ``"cholespy"`` asked for but not installed.
    """
    if name not in BACKENDS:
        raise OptionsError(f"linear_solver={name!r} is not one of {', '.join(map(repr, BACKENDS))}")
    have = available_backends()
    if name == "auto":
        return "cholespy" if "cholespy" in have else "igl"
    if name not in have:
        raise MissingExtraError(
            "linear_solver='cholespy' needs the cholespy package: pip install 'igljoin[fast]' "
            "(or use linear_solver='igl')"
        )
    return name


class FixedQuadratic:
    """A factored ``Q`` (n × n, symmetric positive definite on the free rows) with fixed rows.

    Parameters
    ----------
    Q : sparse matrix, shape (n, n)
    fixed : ndarray of int64, shape (b,)
        Rows held at prescribed values.
    backend : {"auto", "igl", "cholespy"}

    Attributes
    ----------
    backend : str
        The backend used (``"auto"`` resolved).
    free : ndarray of int64, shape (n - b,)
    Qff, Qfb : scipy.sparse.csr_matrix
        Free–free and free–fixed blocks of ``Q``.
    made : int
        Class attribute: factorizations made in this process (every
        backend), so that code and tests can check that a re-solve reused
        one instead of refactoring.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> Q = sp.diags([2.0, 2.0, 2.0]) - sp.eye(3, k=1) - sp.eye(3, k=-1)
    >>> f = FixedQuadratic(Q, np.array([0, 2]), "igl")
    >>> f.solve(np.zeros((3, 1)), np.array([[0.0], [2.0]])).ravel().tolist()
    [0.0, 1.0, 2.0]
    """

    made = 0

    def __init__(self, Q: sp.spmatrix, fixed: np.ndarray, backend: str = "auto"):
        self.backend = resolve_backend(backend)
        Q = sp.csr_matrix(Q)
        n = Q.shape[0]
        self.n = n
        self.fixed = np.asarray(fixed, dtype=np.int64)
        mask = np.ones(n, dtype=bool)
        mask[self.fixed] = False
        self.free = np.flatnonzero(mask)
        rows = Q[self.free]
        self.Qff = sp.csr_matrix(rows[:, self.free])
        self.Qfb = sp.csr_matrix(rows[:, self.fixed])
        if not self.free.size:
            return
        FixedQuadratic.made += 1
        if self.backend == "igl":
            self._data = igl.min_quad_with_fixed_data()
            ok = igl.min_quad_with_fixed_precompute(
                sp.csc_matrix(Q), self.fixed, sp.csc_matrix((0, n)), True, self._data
            )
            if ok is False:
                raise SolveError(_NOT_FACTORED)
        else:
            import cholespy

            A = sp.csc_matrix(self.Qff)
            A.sort_indices()
            try:
                self._chol = cholespy.CholeskySolverD(
                    A.shape[0],
                    A.indptr.astype(np.int32),
                    A.indices.astype(np.int32),
                    np.ascontiguousarray(A.data),
                    cholespy.MatrixType.CSC,
                )
            except (RuntimeError, ValueError) as exc:
                raise SolveError(_NOT_FACTORED) from exc
            # a matrix that is only semidefinite can factor without an error: probe it
            probe = self.solve_free(np.ones((self.free.size, 1)))
            if not np.isfinite(probe).all():
                raise SolveError(_NOT_FACTORED)

    def solve_free(self, b: np.ndarray) -> np.ndarray:
        """``Q_ff⁻¹ b`` for ``b`` of shape (n_free, k); returns shape (n_free, k)."""
        b = np.ascontiguousarray(b, dtype=np.float64)
        if not self.free.size:
            return np.zeros_like(b)
        if self.backend == "cholespy":
            x = np.empty_like(b)
            self._chol.solve(b, x)
            return x
        B = np.zeros((self.n, b.shape[1]))
        B[self.free] = -b
        X = igl.min_quad_with_fixed_solve(
            self._data, B, np.zeros((len(self.fixed), b.shape[1])), np.zeros((0, b.shape[1]))
        )
        return np.asarray(X)[self.free]

    def solve(self, B: np.ndarray, bc: np.ndarray) -> np.ndarray:
        """Minimiser of ``½ xᵀ Q x − xᵀ B`` with ``x[fixed] = bc``.

        Parameters
        ----------
        B : ndarray, shape (n, k)
        bc : ndarray, shape (b, k)

        Returns
        -------
        ndarray, shape (n, k)
        """
        B = np.asarray(B, dtype=np.float64)
        bc = np.asarray(bc, dtype=np.float64)
        k = B.shape[1]
        X = np.empty((self.n, k))
        X[self.fixed] = bc
        if not self.free.size:
            return X
        if self.backend == "igl":
            out = igl.min_quad_with_fixed_solve(self._data, -B, bc, np.zeros((0, k)))
            return np.asarray(out)
        X[self.free] = self.solve_free(B[self.free] - self.Qfb @ bc)
        return X
