"""A Gauss–Newton model of the join energy with the per-vertex rotations eliminated.

The preconditioner of the local/global iteration (:mod:`igljoin.solve`),
``P = Σ c_t K_tᵀ W_t K_t``, is the same for the three coordinates and does
not know that a vertex's neighbourhood may turn at little cost: the
rotation-aware shape term refits its rotation. That is why its iteration
count grows with the mesh. This module builds the 3n × 3n model that does
know it, at the current iterate ``X``:

* **Shape term** (rotation-aware): the residual of a row owned by vertex
  ``i`` is ``a − R_i b``; with the rotation perturbed as ``(I + [θ]×) R_i``
  the joint Gauss–Newton matrix in ``(X, θ_i)`` is
  ``[Kᵀ W K ⊗ I, M_i; M_iᵀ, S_i]`` with ``M_i = Σ w Kᵀ [c]×`` and
  ``S_i = Σ w (|c|² I − c cᵀ)``, ``c = R_i b`` the target. Eliminating each
  ``θ_i`` leaves ``Kᵀ W K ⊗ I − Σ_i M_i S_i⁻¹ M_iᵀ``: the rotations'
  freedom removed from the stiffness, on each vertex's closed one-ring
  (no more fill than ``LᵀL`` already has). As a Schur complement of a
  positive semidefinite matrix it is positive semidefinite.
* **Stretch term**: the Hessian of half the squared distance to a sphere of
  rest length ``L₀``, ``k (êêᵀ + max(0, 1 − L₀/|e|) (I − êêᵀ))`` — clamped
  so that a compressed edge adds no negative stiffness.
* **Smooth join** (a target that is the projection onto a half-plane or a
  wedge): ``w m mᵀ`` with ``m`` the unit residual, the normal of the face
  the row is projected onto (the exact Hessian of half the squared
  distance to a flat face); a row inside the wedge adds nothing; a fixed
  target (``smooth_mode="paper"``) adds ``w I``.
* Any other term: ``Kᵀ W K ⊗ I``.

Coordinates are ordered vertex-major (``3 i + c``). The matrix is half the
Gauss–Newton Hessian of ``E``, the scale of the half gradient the solver
uses.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from .linsolve import FixedQuadratic
from .terms import ROTATION_REGULARISATION, LocalState, ShapeTerm, SmoothJoinTerm, StretchTerm

__all__ = ["gauss_newton", "dofs", "NewtonModel"]


def _cross(c: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[c]×`` (k, 3, 3) of vectors ``c`` (k, 3)."""
    out = np.zeros((len(c), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -c[:, 2], c[:, 1]
    out[:, 1, 0], out[:, 1, 2] = c[:, 2], -c[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -c[:, 1], c[:, 0]
    return out


def _inertia(c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``w (|c|² I − c cᵀ)`` (k, 3, 3) for vectors ``c`` (k, 3) and weights ``w`` (k,)."""
    out = -c[:, :, None] * c[:, None, :]
    s = np.einsum("ij,ij->i", c, c)
    out[:, 0, 0] += s
    out[:, 1, 1] += s
    out[:, 2, 2] += s
    return out * w[:, None, None]


def _row_pairs(indptr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs ``(p, q)`` of entry positions in the same row of a CSR pattern."""
    length = np.diff(indptr)
    row_of = np.repeat(np.arange(len(length)), length)
    p = np.repeat(np.arange(indptr[-1]), length[row_of])
    # q runs over the row of p: offsets 0..len-1 from the row start
    start = np.repeat(indptr[row_of], length[row_of])
    first = np.r_[0, np.cumsum(length[row_of])[:-1]]
    offset = np.arange(len(p)) - np.repeat(first, length[row_of])
    return p, start + offset


def _assemble(parts: list, n: int) -> sp.csr_matrix:
    """Sum of 3 × 3 blocks as a 3n × 3n matrix.

    ``parts`` is a list of ``(i, j, blocks)``: vertex indices (k,) each and
    blocks (k, 3, 3), added at rows ``3 i + a``, columns ``3 j + b``.
    """
    i = np.concatenate([p[0] for p in parts])
    j = np.concatenate([p[1] for p in parts])
    blocks = np.concatenate([p[2] for p in parts])
    # block sparse rows: sum the duplicate blocks, then expand to CSR
    key = i * n + j
    order = np.argsort(key, kind="stable")
    unique, start = np.unique(key[order], return_index=True)
    summed = np.add.reduceat(blocks[order], start, axis=0) if len(order) else blocks
    bsr = sp.bsr_matrix(
        (summed, unique % n, np.searchsorted(unique // n, np.arange(n + 1))), shape=(3 * n, 3 * n)
    )
    return bsr.tocsr()


def _isotropic(Q: sp.spmatrix) -> tuple:
    """Blocks of ``Q ⊗ I₃`` for a scalar quadratic form ``Q`` (n × n)."""
    Q = sp.coo_matrix(Q)
    return Q.row.astype(np.int64), Q.col.astype(np.int64), Q.data[:, None, None] * np.eye(3)


def _shape(term: ShapeTerm, state: LocalState) -> list:
    n = term.n
    base = _isotropic(term.quadratic())
    if not term.rotation_aware:
        return [base]
    R = state.rotations
    w, mu = term.weight, ROTATION_REGULARISATION
    L = sp.csr_matrix(term.L, copy=True)  # sorted below; the term keeps its own
    L.sort_indices()
    rows = np.repeat(np.arange(n), np.diff(L.indptr))
    keys = rows * n + L.indices
    # the Laplacian row of vertex i: target c = R_i δ_i, coefficient L[i, v] at v
    c_lap = np.einsum("nij,nj->ni", R, term.delta)
    M = (w * L.data)[:, None, None] * _cross(c_lap)[rows]
    S = _inertia(c_lap, np.full(n, w))
    # one-ring edge rows owned by each end: +[c]× at the owner, −[c]× at the other end
    E = term.E
    for own, other, sign in ((0, 1, 1.0), (1, 0, -1.0)):
        o, t = E[:, own], E[:, other]
        c = sign * np.einsum("eij,ej->ei", R[o], term.rest_edges)
        X = (w * mu) * _cross(c)
        np.add.at(M, np.searchsorted(keys, o * n + o), X)
        np.add.at(M, np.searchsorted(keys, o * n + t), -X)
        np.add.at(S, o, _inertia(c, np.full(len(c), w * mu)))
    # eliminate the rotations: − Σ_i M_i S_i⁻¹ M_iᵀ on the closed one-ring of i
    Z = np.linalg.cholesky(np.linalg.inv(S))  # S⁻¹ = Z Zᵀ
    N = np.einsum("pab,pbc->pac", M, Z[rows])
    p, q = _row_pairs(L.indptr)
    blocks = np.einsum("pac,pbc->pab", N[p], N[q])
    return [base, (L.indices[p], L.indices[q], -blocks)]


def _stretch(term: StretchTerm, state: LocalState) -> list:
    d = term.applied(state)
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    across = np.clip(1.0 - term.rest_length / np.maximum(length, 1e-300), 0.0, None)
    uu = u[:, :, None] * u[:, None, :]
    h = uu + across[:, None, None] * (np.eye(3)[None] - uu)
    h *= term.weights[:, None, None]
    a, b = term.E[:, 0], term.E[:, 1]
    return [(np.concatenate([a, b, a, b]), np.concatenate([a, b, b, a]),
             np.concatenate([h, h, -h, -h]))]  # fmt: skip


def _row_hessians(term: SmoothJoinTerm, state: LocalState) -> np.ndarray:
    """Per-row 3 × 3 Hessians of half the squared distance to the row's target set."""
    k = term.K.shape[0]
    if term.mode == "paper":
        return np.broadcast_to(np.eye(3), (k, 3, 3)).copy()
    r = term.applied(state) - term.target(state)
    size = np.linalg.norm(r, axis=1)
    scale = np.linalg.norm(term.applied(state), axis=1)
    moved = size > 1e-12 * np.maximum(scale, 1e-300)
    m = np.where(moved[:, None], r / np.where(moved, size, 1.0)[:, None], term.normal)
    H = m[:, :, None] * m[:, None, :]
    # a row exactly on a face: the face's normal; exactly inside a wedge: nothing
    tol = np.broadcast_to(np.asarray(term.tolerance, dtype=np.float64), (k,))
    H[~moved & (tol > 0)] = 0.0
    return H


def _rows(K: sp.csr_matrix, weights: np.ndarray, H: np.ndarray) -> list:
    """``Σ_r w_r K_rᵀ K_r ⊗ H_r`` for a CSR ``K`` (rows × n) and ``H`` (rows, 3, 3)."""
    K = sp.csr_matrix(K, copy=True)
    K.sort_indices()
    rows = np.repeat(np.arange(K.shape[0]), np.diff(K.indptr))
    p, q = _row_pairs(K.indptr)
    coef = weights[rows[p]] * K.data[p] * K.data[q]
    return [(K.indices[p], K.indices[q], coef[:, None, None] * H[rows[p]])]


def gauss_newton(terms: list, state: LocalState, n: int) -> sp.csr_matrix:
    """Half the Gauss–Newton Hessian of the join energy at ``state.X``, shape (3n, 3n).

    Parameters
    ----------
    terms : list of Term
    state : LocalState
        A local step's state at ``X`` (n, 3), with ``rotations`` fitted.
    n : int
        Number of vertices.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3n, 3n)
        Symmetric positive semidefinite; vertex-major coordinates.
    """
    parts = []
    for term in terms:
        if isinstance(term, ShapeTerm):
            parts += _shape(term, state)
        elif isinstance(term, StretchTerm):
            parts += _stretch(term, state)
        elif isinstance(term, SmoothJoinTerm):
            parts += _rows(term.K, term.weights, _row_hessians(term, state))
        else:
            parts.append(_isotropic(term.quadratic()))
    return _assemble(parts, n)


def dofs(fixed: np.ndarray) -> np.ndarray:
    """Vertex-major coordinates ``3 i + c`` of the vertices ``fixed`` (b,), shape (3b,)."""
    fixed = np.asarray(fixed, dtype=np.int64)
    return (3 * fixed[:, None] + np.arange(3)[None, :]).reshape(-1)


class NewtonModel:
    """The Gauss–Newton model as the quasi-Newton solver's initial inverse Hessian.

    Passed as ``model`` to :meth:`igljoin.solve.LocalGlobalSolver.run`: every
    ``every`` iterations it assembles :func:`gauss_newton` at the current
    iterate and factors its free–free block (3 n_free × 3 n_free); in
    between, the quasi-Newton pairs correct the lagging model.

    Parameters
    ----------
    solver : LocalGlobalSolver
        Supplies the terms, the fixed vertices and the backend.
    every : int
        Iterations between refactorizations (1: a Newton step every
        iteration; default: once, at the start of the run). Measured on the
        paper's samples, once is the cheapest: refactoring every 5
        iterations saves a few iterations at several times the cost.

    Attributes
    ----------
    factorizations : int
    seconds : dict
        ``assemble`` and ``factor`` times.
    """

    def __init__(self, solver, every: int = 1_000_000):
        self.solver = solver
        self.every = max(int(every), 1)
        self.fixed = dofs(solver.fixed)
        self.factor = None
        self.factorizations = 0
        self.seconds = {"assemble": 0.0, "factor": 0.0}

    def refresh(self, state: LocalState, iteration: int) -> bool:
        """Refactor at ``state`` when due; ``True`` if the model changed."""
        if self.factor is not None and (iteration - 1) % self.every:
            return False
        t0 = time.perf_counter()
        H = gauss_newton(self.solver.terms, state, self.solver.n)
        t1 = time.perf_counter()
        self.factor = FixedQuadratic(H, self.fixed, self.solver.linear_solver)
        self.seconds["assemble"] += t1 - t0
        self.seconds["factor"] += time.perf_counter() - t1
        self.factorizations += 1
        return True

    def solve_free(self, v: np.ndarray) -> np.ndarray:
        """The model's inverse on ``v`` (n_free, 3); returns shape (n_free, 3)."""
        out = self.factor.solve_free(np.ascontiguousarray(v).reshape(-1, 1))
        return out.reshape(v.shape)
