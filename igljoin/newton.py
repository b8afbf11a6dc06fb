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
from scipy.sparse import get_index_dtype

from .errors import OptionsError
from .linsolve import FixedQuadratic
from .terms import (
    ROTATION_REGULARISATION,
    LocalState,
    ShapeTerm,
    SmoothJoinTerm,
    StretchTerm,
    band_couplings,
    row_patterns,
)

__all__ = [
    "gauss_newton",
    "gauss_newton_factors",
    "factors_product",
    "factor_rows",
    "rotation_pattern",
    "row_directions",
    "factor_entries",
    "dofs",
    "assembled_entries",
    "NewtonModel",
    "MAX_MODEL_ENTRIES",
]

#: Largest count of :func:`assembled_entries` :class:`NewtonModel` builds. Measured with
#: the default backend, the assembly and factorization peak at 50-73 bytes per counted
#: entry above the solver's own memory: 50 (1.3k patch, 4.6e5 entries, cholespy), 62
#: (2.5k tube, 1.0e6), 56 (10k patch, 7.5e6, 0.42 GB), 73 (10k tube, 6.5e6), 50 (20k
#: patch, 2.1e7, Pardiso), 51 (30k patch, 4.0e7, 2.1 GB) and 51 (44k patch, 8.1e7, 4.2
#: GB). 1e8 entries are 5-7.5 GB; the 10k patch, the largest model the benchmark builds,
#: counts 7.5e6. Past it the model is refused (an ``OptionsError``).
MAX_MODEL_ENTRIES = 100_000_000

#: Bytes the assembly and factorization spend per counted entry (the 50-73 measured above,
#: rounded up).
_BYTES_PER_ENTRY = 75


def _kron3(K: sp.spmatrix, H: np.ndarray | None = None, cache: dict | None = None) -> sp.csr_matrix:
    """Rows ``K_r ⊗ m_r`` (one per row, ``H`` of shape (rows, 3)) or ``K ⊗ I₃`` (``H`` None).

    With a ``cache`` dict, ``K``'s pattern (and ``K ⊗ I₃`` whole) is kept
    there and only the values are computed on the next call.
    """
    key = (id(K), H is None)
    if cache is not None and key in cache:
        hit = cache[key]
        if H is None:
            return hit
        rows, Kdata, cols, indptr, shape = hit
    elif H is None:
        out = sp.csr_matrix(sp.kron(sp.csr_matrix(K), sp.eye(3), format="csr"))
        if cache is not None:
            cache[key] = out
        return out
    else:
        K = sp.csr_matrix(K)
        rows = np.repeat(np.arange(K.shape[0]), np.diff(K.indptr))
        Kdata = K.data
        cols = (3 * K.indices[:, None] + np.arange(3)[None, :]).reshape(-1)
        indptr = 3 * K.indptr
        shape = (K.shape[0], 3 * K.shape[1])
        if cache is not None:
            # the index type scipy would convert them to on every call
            cols, indptr = _index_arrays(cols, indptr, shape)
            cache[key] = (rows, Kdata, cols, indptr, shape)
    data = (Kdata[:, None] * H[rows]).reshape(-1)
    return sp.csr_matrix((data, cols, indptr), shape=shape)


def _index_arrays(cols: np.ndarray, indptr: np.ndarray, shape: tuple) -> tuple:
    """CSR index arrays in the integer type scipy picks for them (no conversion per use)."""
    kind = get_index_dtype((cols, indptr), maxval=max(shape[0], shape[1], len(cols)))
    return cols.astype(kind), indptr.astype(kind)


def _unit_rows(term) -> tuple:
    """``K ⊗ I₃`` as rows: the three unit directions of every row, weights (r, 3)."""
    weights = np.asarray(term.weights, dtype=np.float64)
    return (term.K, None, np.broadcast_to(weights[:, None], (len(weights), 3)))


def _stretch_rows(term: StretchTerm, state: LocalState) -> tuple:
    d = term.applied(state)
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    across = np.clip(1.0 - term.rest_length / np.maximum(length, 1e-300), 0.0, None)
    # k (u uᵀ + s (I − u uᵀ)) = k u uᵀ + k s Σ_c p_c p_cᵀ with p_c the rows of I − u uᵀ
    directions = np.empty((len(u), 4, 3))
    directions[:, 0] = u
    directions[:, 1:] = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    across = term.weights * across
    return (term.K, directions, np.stack([term.weights, across, across, across], 1))


def _smooth_rows(term: SmoothJoinTerm, state: LocalState) -> tuple:
    if term.mode == "paper":
        return _unit_rows(term)
    k = term.K.shape[0]
    applied = term.applied(state)
    r = applied - term.target(state)
    size = np.linalg.norm(r, axis=1)
    scale = np.linalg.norm(applied, axis=1)
    moved = size > 1e-12 * np.maximum(scale, 1e-300)
    m = np.where(moved[:, None], r / np.where(moved, size, 1.0)[:, None], term.normal)
    # a row exactly on a face: the face's normal; exactly inside a wedge: nothing
    tol = np.broadcast_to(np.asarray(term.tolerance, dtype=np.float64), (k,))
    m = np.where((~moved & (tol > 0))[:, None], 0.0, m)
    return (term.K, m[:, None, :], np.asarray(term.weights, dtype=np.float64)[:, None])


def factor_rows(term, state: LocalState, cache: dict | None = None) -> tuple:
    """``term``'s part of :func:`gauss_newton_factors` as rows of its operators.

    Every factor row is a row ``K_r`` of the term's operator times a
    direction ``d`` in the coordinates, ``K_r ⊗ d`` (shape (3n,)): ``K ⊗ I₃``
    is every row with the three unit directions, the stretch term's four
    factors the direction of the edge and the rows of ``I − u uᵀ``, the
    smooth join's one factor the unit residual. The eliminated rotations of
    a rotation-aware shape term, the factor with the minus sign, are
    returned as the values of its blocks (:func:`rotation_pattern`).

    Parameters
    ----------
    term : Term
    state : LocalState
        A local step's state (n, 3), with ``rotations`` fitted.
    cache : dict, optional
        As :func:`gauss_newton_factors`'s (the rotations' kernel inputs).

    Returns
    -------
    rows : (scipy.sparse matrix, ndarray or None, ndarray)
        ``(K, directions, weights)``: ``K`` of shape (r, n); ``directions``
        of shape (r, D, 3), or ``None`` for the three unit directions
        (``D = 3``); ``weights`` of shape (r, D), ≥ 0, row ``K_r ⊗ d``'s
        weight at ``[r, d]``. Their sign is +1.
    rotation : ndarray, shape (9 p,), or None
        The values of ``C`` (``Σ_i M_i S_i⁻¹ M_iᵀ = CᵀC``, sign −1, unit
        weights) for a rotation-aware shape term, ``p`` the entries of its
        Laplacian: :func:`igljoin.coarse_kernels.rotation_factor`'s layout.
    """
    if isinstance(term, ShapeTerm):
        return _unit_rows(term), _rotation_values(term, state, {} if cache is None else cache)
    if isinstance(term, StretchTerm):
        return _stretch_rows(term, state), None
    if isinstance(term, SmoothJoinTerm):
        return _smooth_rows(term, state), None
    return _unit_rows(term), None


def rotation_pattern(term: ShapeTerm, cache: dict) -> tuple:
    """The rotations' kernel inputs for a rotation-aware ``term``, kept in ``cache``.

    Returns
    -------
    tuple
        ``((indptr, indices, data), E, rest, delta, own_own, own_other)``:
        the Laplacian ``L`` in CSR form with sorted columns (int64 indices;
        the rows of ``C`` are ``3 i + c`` for its rows ``i``, their entries
        three per entry of ``L``) and the arguments of
        :func:`igljoin.coarse_kernels.rotation_factor` that do not change.
    """
    key = (id(term), "rotations")
    if key not in cache:
        n = term.n
        L = sp.csr_matrix(term.L, copy=True)
        L.sort_indices()
        keys = np.repeat(np.arange(n), np.diff(L.indptr)) * n + L.indices
        E = np.ascontiguousarray(term.E, dtype=np.int64)
        own_own = np.stack([np.searchsorted(keys, E[:, k] * n + E[:, k]) for k in (0, 1)])
        own_other = np.stack([np.searchsorted(keys, E[:, k] * n + E[:, 1 - k]) for k in (0, 1)])
        cache[key] = (
            (L.indptr.astype(np.int64), L.indices.astype(np.int64), L.data),
            E,
            np.ascontiguousarray(term.rest_edges, dtype=np.float64),
            np.ascontiguousarray(term.delta, dtype=np.float64),
            own_own,
            own_other,
        )
    return cache[key]


def _rotation_values(term: ShapeTerm, state: LocalState, cache: dict) -> np.ndarray | None:
    """The values of the rotations' elimination factor ``C`` (compiled), or None."""
    if not term.rotation_aware:
        return None
    from .coarse_kernels import rotation_factor

    L, E, rest, delta, own_own, own_other = rotation_pattern(term, cache)
    R = np.ascontiguousarray(state.rotations, dtype=np.float64)
    return rotation_factor(
        *L, R, delta, E, rest, own_own, own_other, float(term.weight),
        float(ROTATION_REGULARISATION),
    )  # fmt: skip


def _rotation_matrix(term: ShapeTerm, values: np.ndarray, cache: dict) -> sp.csr_matrix:
    """``C`` of shape (3n, 3n) from its values, its index arrays kept in ``cache``."""
    key = (id(term), "rotation matrix")
    if key not in cache:
        (Lptr, Lind, _), *_ = rotation_pattern(term, cache)
        n, nnz = term.n, len(Lind)
        count = np.diff(Lptr)
        # row 3 i + c: 3 entries (columns 3 v + a) per entry v of L's row i
        indptr = np.r_[0, np.cumsum(np.repeat(3 * count, 3))].astype(np.int64)
        rows = np.repeat(np.arange(n), count)
        cols = np.empty(9 * nnz, dtype=np.int64)
        for i_c in range(3):
            start = 9 * Lptr[rows] + 3 * i_c * count[rows] + 3 * (np.arange(nnz) - Lptr[rows])
            for a in range(3):
                cols[start + a] = 3 * Lind + a
        cache[key] = _index_arrays(cols, indptr, (3 * n, 3 * n))
    cols, indptr = cache[key]
    return sp.csr_matrix((values, cols, indptr), shape=(3 * term.n, 3 * term.n))


def factors_product(factors: list, free_dofs: np.ndarray, n: int, v: np.ndarray) -> np.ndarray:
    """``H_ff v`` from :func:`gauss_newton_factors`' ``factors`` (``Σ s Jᵀ diag(w) J``).

    Parameters
    ----------
    factors : list of (scipy.sparse matrix, ndarray, float)
    free_dofs : ndarray of int64, shape (3 n_free,)
        The free degrees of freedom (:func:`dofs` of the free vertices).
    n : int
        Vertices (the factors act on 3n degrees of freedom).
    v : ndarray, shape (3 n_free,)

    Returns
    -------
    ndarray, shape (3 n_free,)
    """
    full = np.zeros(3 * n)
    full[free_dofs] = v
    out = np.zeros_like(full)
    for J, w, sign in factors:
        out += sign * (J.T @ (w * (J @ full)))
    return out[free_dofs]


def gauss_newton_factors(terms: list, state: LocalState, n: int, cache: dict | None = None) -> list:
    """Half the Gauss–Newton Hessian at ``state.X`` as a signed sum ``Σ s Jᵀ diag(w) J``.

    The factored form costs as many entries as the terms' operators (a band
    row of the smooth join couples ~50 vertices: 150 entries in ``J``,
    22,500 in ``JᵀJ``); products with it and projections ``(J A)ᵀ W (J A)``
    onto a few columns ``A`` are cheap where the assembled matrix is not.
    :func:`factor_rows` gives the same factors without forming ``J``.

    Parameters
    ----------
    terms : list of Term
    state : LocalState
        A local step's state at ``X`` (n, 3), with ``rotations`` fitted.
    n : int
        Number of vertices.
    cache : dict, optional
        Kept by a caller that asks again for the same terms: the factors'
        patterns are stored in it on the first call, and later calls
        compute their values only. The same matrices as without it.

    Returns
    -------
    list of (scipy.sparse.csr_matrix, ndarray, float)
        ``(J, w, s)``: ``J`` of shape (r, 3n) on vertex-major coordinates,
        weights ``w`` (r,) ≥ 0 and the sign ``s`` (−1 for the eliminated
        rotations).
    """
    cache = {} if cache is None else cache
    parts = []
    for term in terms:
        (K, directions, weights), rotation = factor_rows(term, state, cache)
        if directions is None:
            parts.append((_kron3(K, cache=cache), weights.reshape(-1), 1.0))
        else:
            parts += [
                (_kron3(K, directions[:, d], cache), weights[:, d], 1.0)
                for d in range(directions.shape[1])
            ]
        if rotation is not None:
            parts.append((_rotation_matrix(term, rotation, cache), np.ones(3 * term.n), -1.0))
    return parts


def row_directions(term) -> int:
    """Factor rows per row of ``term``'s operator ``K`` (:func:`factor_rows`' ``D``).

    Four for the stretch term, one for the smooth join's projections, three
    (``K ⊗ I₃``) otherwise; a rotation-aware shape term's eliminated
    rotations are counted by :func:`factor_entries` apart.
    """
    if isinstance(term, StretchTerm):
        return 4
    if isinstance(term, SmoothJoinTerm) and term.mode != "paper":
        return 1
    return 3


def factor_entries(term) -> int:
    """Stored entries of ``term``'s factors in :func:`gauss_newton_factors`, from its patterns.

    Counted without building them: three per entry of the term's operator
    ``K`` in each factor (``K ⊗ I₃`` or rows ``K_r ⊗ m_r``) — one factor,
    four for the stretch term — and nine per entry of the Laplacian ``L``
    for the eliminated rotations of a rotation-aware shape term.

    Parameters
    ----------
    term : Term

    Returns
    -------
    int
    """
    nnz = sum(block.nnz for block in row_patterns(term))
    D = row_directions(term)
    # K ⊗ I₃ (D = 3) holds one entry per entry of K in each of its three rows; each of the
    # D factors of rows K_r ⊗ d three
    nnz *= 3 if D == 3 else 3 * D
    if isinstance(term, ShapeTerm) and term.rotation_aware:
        return nnz + 9 * term.L.nnz
    return nnz


def assembled_entries(terms: list) -> int:
    """Entries counted for :func:`gauss_newton`'s matrix, from the terms' patterns alone.

    Nine (a 3 × 3 block) per vertex pair each term's operator ``K``
    couples, the non-zeros of ``Kᵀ K`` (the band smooth join's kept
    ``couplings``, :func:`igljoin.terms.band_couplings` for the others: an
    estimate from sampled columns, exact where the samples cover them all):
    more than the assembled matrix stores where the terms' patterns overlap.
    Nothing of the model is built.

    Parameters
    ----------
    terms : list of Term

    Returns
    -------
    int
    """
    pairs = 0.0
    for term in terms:
        kept = getattr(term, "couplings", None)
        pairs += kept if kept is not None else band_couplings(_counted_rows(term))
    return int(round(9 * pairs))


def _counted_rows(term) -> sp.csr_matrix:
    """Rows with the pattern of ``term``'s ``Kᵀ K``, for the count.

    A rotation-aware shape term's ``K`` is a stack it keeps once made (0.26 GB
    at 1M guest vertices); its blocks' patterns
    (:func:`igljoin.terms.row_patterns`), each distinct one once (``−D``'s is
    ``D``'s, the same matrix), stacked for the count couple the same pairs and
    are let go after it.
    """
    blocks = list({id(block): block for block in row_patterns(term)}.values())
    return blocks[0] if len(blocks) == 1 else sp.csr_matrix(sp.vstack(blocks, format="csr"))


def gauss_newton(terms: list, state: LocalState, n: int) -> sp.csr_matrix:
    """Half the Gauss–Newton Hessian of the join energy at ``state.X``, shape (3n, 3n).

    :func:`gauss_newton_factors` assembled; the parameters are its own.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3n, 3n)
        Symmetric positive semidefinite; vertex-major coordinates.
    """
    H = sp.csr_matrix((3 * n, 3 * n))
    for J, w, sign in gauss_newton_factors(terms, state, n):
        H = H + sign * (J.T @ sp.diags(w) @ J)
    return sp.csr_matrix(H)


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
    entries : int
        :func:`assembled_entries` of the solver's terms, counted at
        construction.
    factorizations : int
    seconds : dict
        ``assemble`` and ``factor`` times.

    Raises
    ------
    OptionsError
        The model would hold more than :data:`MAX_MODEL_ENTRIES` entries
        (counted before anything is built).
    """

    def __init__(self, solver, every: int = 1_000_000):
        self.solver = solver
        self.entries = assembled_entries(solver.terms)
        if self.entries > MAX_MODEL_ENTRIES:
            raise OptionsError(
                f"the Gauss–Newton model would hold about {self.entries:,} entries (a 3 x 3 "
                f"block per vertex pair its terms couple, at {solver.n:,} guest vertices), "
                f"more than igljoin.newton.MAX_MODEL_ENTRIES = {MAX_MODEL_ENTRIES:,} (about "
                f"{_BYTES_PER_ENTRY * self.entries / 1e9:.2g} GB to assemble and factor): run "
                "without it (the factored preconditioner P) or with "
                "preconditioner='two-level' (the model on clusters' motions), or raise "
                "igljoin.newton.MAX_MODEL_ENTRIES"
            )
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
