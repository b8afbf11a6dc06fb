"""Prefactored solves of a sparse quadratic form with fixed rows (linear-solver backends).

The global step of the join minimises ``½ xᵀ Q x − xᵀ B`` with the rows
``fixed`` held at ``bc``: ``Q_ff x_f = B_f − Q_fb bc``. ``Q`` never changes
during a solve, so it is factored once and every iteration is a
back-substitution. Three backends give the same answer (to rounding):

* ``"igl"`` — libigl's ``min_quad_with_fixed_precompute`` / ``_solve``;
  always available (libigl is a dependency).
* ``"cholespy"`` — a sparse (simplicial) Cholesky of ``Q_ff`` (the
  ``igljoin[fast]`` extra); its back-substitutions are several times faster
  (0.2 ms for a paper-sized guest, the fastest of the backends measured in
  docs/benchmarks.md).
* ``"pardiso"`` — MKL Pardiso's supernodal Cholesky (METIS nested
  dissection) of ``Q_ff``, called through ctypes from the ``mkl`` wheel's
  ``libmkl_rt`` (the ``igljoin[pardiso]`` extra; Intel Simplified Software
  License: free to use and redistribute, binary only). The factorization
  runs on MKL's threads (``MKL_NUM_THREADS``), each back-solve on one
  (two were no faster under load; on a quiet machine the 100k patch's
  augmented 3-column back-solve took 49 against 60 ms with two, while on one
  the two-level model's coarse solve runs beside it on the other core:
  :meth:`igljoin.twolevel.TwoLevelModel.solve_free`).

``"auto"`` picks Pardiso for systems of :data:`PARDISO_FROM_NNZ` (10
million) stored nonzeros and more and cholespy below, each when it is
installed, and libigl otherwise. The number of nonzeros, not of rows,
decides: Pardiso's gain is its faster factorization, which counts where
the preconditioner is dense (the default band smooth-join term passes 10
million nonzeros at about 55k guest vertices) or very large.

Why (``pipelines/factor_study.py`` on the join's own preconditioner ``P_ff``,
partial patch guests; 2 shared cores under load, so the ratios count more
than the seconds). Default options (band smooth join):

| free rows | backend | factor (s) | 3-col back-solve (ms) | factor + it × back-solve (s) |
|---:|---|---:|---:|---:|
| 9,478 (0.45 M nonzeros) | cholespy | 0.51 | 17.1 | 2.2 (100 it) |
| | pardiso | 0.38 | 17.3 | 2.1 |
| 28,046 (3.0 M) | cholespy | 5.4 | 82 | 19.4 (172 it) |
| | pardiso | 1.9 | 77 | 15.2 |
| 93,738 (30 M) | cholespy | 170 | 600 | 320 (250 it) |
| | pardiso | 20 | 292 | 93 |

``smooth_mode="robust"`` (a sparser ``P``; the 1M guest is the end-to-end
tube, whose band-mode ``P`` is too dense to assemble: about 560 nonzeros a
row at 160k, growing with the guest's resolution):

| free rows | backend | factor (s) | 3-col back-solve (ms) | factor + it × back-solve (s) |
|---:|---|---:|---:|---:|
| 9,478 (0.18 M nonzeros) | cholespy | 0.25 | 3.1 | 0.6 (100 it) |
| | pardiso | 0.40 | 16.7 | 2.1 |
| 28,046 (0.54 M) | cholespy | 1.1 | 46 | 8.9 (172 it) |
| | pardiso | 0.66 | 54 | 9.9 |
| 93,738 (1.8 M) | cholespy | 6.4 | 135 | 40.1 (250 it) |
| | pardiso | 2.4 | 147 | 39.2 |
| 997,858 (23 M) | cholespy | 264 | 1,328 | 928 (500 it) |
| | pardiso | 29 | 1,059 | 558 |

Pardiso factors 3 to 9 × faster from 3 M nonzeros on; its back-solve is
5 × slower on the sparse 10k system and, inside a join, about 1.15 ×
slower at 100k (the study alone, under load, timed it faster). Whole
joins of the 100k patch (default options, alternated runs, seconds; the
same 248 iterations, final energies 2e-12 apart):

| backend | join (3 runs) | factor (median) | back-solves (median) |
|---|---|---:|---:|
| pardiso | 173.9, 124.8, 133.3 | 31.2 | 51.7 |
| cholespy | 130.4, 162.9, 199.2 | 86.1 | 44.9 |

so Pardiso saves a fifth of the 100k join (medians 133 against 163 s) and
more at 1M (robust; the study only), while from 2 to 3 M nonzeros (30k
band guest, 100k robust guest) the two are within the noise of a whole
join: hence 10 M.
Measured and not chosen: scipy's SuperLU (symmetric mode, no pivoting)
factors faster than cholespy on the dense band systems but back-solves 2 ×
slower; a nested-dissection (METIS) or reverse Cuthill–McKee order given
to cholespy changes nothing (CHOLMOD reorders with its own nested
dissection, NESDIS); QDLDL and pypardiso's own ``spsolve`` (it hashes
the matrix on every call and treats it as unsymmetric) back-solve 3 to 7 ×
slower; two MKL threads made the back-solve slower or no faster (4 ×
slower at 10k), which is why it runs on one.

:class:`AugmentedQuadratic` solves ``S + c Kᵀ W K`` without forming the
dense block ``Kᵀ W K`` of long rows (the band smooth join on a guest much
finer than its band), through Pardiso's symmetric indefinite LDLᵀ of the
augmented system; :class:`igljoin.solve.LocalGlobalSolver` picks it by
:data:`igljoin.solve.AUGMENT_FROM_COUPLINGS`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import importlib.metadata
import importlib.util
import weakref

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse import get_index_dtype

from .errors import MissingExtraError, OptionsError, SolveError

__all__ = [
    "BACKENDS",
    "PARDISO_FROM_NNZ",
    "AugmentedQuadratic",
    "FixedQuadratic",
    "augmented_upper",
    "available_backends",
    "resolve_backend",
]

#: Names accepted by ``linear_solver``.
BACKENDS = ("auto", "igl", "cholespy", "pardiso")

#: Stored nonzeros of ``Q_ff`` from which ``"auto"`` factors with Pardiso when it is
#: installed (the measured crossing: see the module docstring).
PARDISO_FROM_NNZ = 10_000_000

# the largest index (and entry count) LP64 Pardiso's 32-bit integers hold
_LP64_MAX = 2**31 - 1

_NOT_FACTORED = (
    "the deformation system could not be factored (a part of the guest is not held by any "
    "term); check that every guest component touches the seam"
)

_EXTRAS = {"cholespy": ("cholespy", "fast"), "pardiso": ("mkl", "pardiso")}


def _installed(backend: str) -> bool:
    if backend == "igl":
        return True
    if backend == "cholespy":
        return importlib.util.find_spec("cholespy") is not None
    # looked for only when needed (~40 ms); a library that is found but does not load (or
    # is not MKL's) counts as missing
    if _mkl_rt_path() is None:
        return False
    try:
        _mkl_rt()
    except (OSError, AttributeError):
        return False
    return True


def available_backends() -> list[str]:
    """Backends that can run here (``"igl"`` always; the others if installed)."""
    return [b for b in BACKENDS[1:] if _installed(b)]


def resolve_backend(name: str, nnz: int | None = None) -> str:
    """The concrete backend for ``name``.

    ``"auto"`` is Pardiso for a system of ``nnz >= PARDISO_FROM_NNZ``
    stored nonzeros when it is installed, else cholespy when installed, else
    libigl.

    Parameters
    ----------
    name : {"auto", "igl", "cholespy", "pardiso"}
    nnz : int, optional
        Stored nonzeros of the system to factor (``None``: a small one).

    Raises
    ------
    OptionsError
        Unknown name.
    MissingExtraError
        ``"cholespy"`` or ``"pardiso"`` asked for but not installed.
    """
    if name not in BACKENDS:
        raise OptionsError(f"linear_solver={name!r} is not one of {', '.join(map(repr, BACKENDS))}")
    if name == "auto":
        if nnz is not None and nnz >= PARDISO_FROM_NNZ and _installed("pardiso"):
            return "pardiso"
        return "cholespy" if _installed("cholespy") else "igl"
    if not _installed(name):
        package, extra = _EXTRAS[name]
        raise MissingExtraError(
            f"linear_solver={name!r} needs the {package} package, which is not installed: "
            f"pip install 'igljoin[{extra}]' (or use linear_solver='igl')"
        )
    return name


# -- MKL Pardiso through ctypes -------------------------------------------------------------

_PARDISO_ERRORS = {
    -1: "input inconsistent",
    -2: "not enough memory",
    -3: "reordering problem",
    -4: "zero pivot (the matrix is not positive definite)",
    -5: "internal error",
    -6: "reordering failed",
    -7: "diagonal matrix problem",
    -8: "32-bit integer overflow",
}


class _PardisoError(RuntimeError):
    """Pardiso returned an error code (the message says which)."""

    def __init__(self, phase: int, code: int):
        self.code = code
        what = _PARDISO_ERRORS.get(code, "unclassified error")
        super().__init__(f"Pardiso phase {phase} failed with error {code} ({what})")


@functools.lru_cache(maxsize=1)
def _mkl_rt_path() -> str | None:
    """Path of MKL's single dynamic library: from the ``mkl`` wheel, else the system's."""
    try:
        files = importlib.metadata.files("mkl") or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    for f in files:
        if f.name.startswith(("libmkl_rt.", "mkl_rt.")):
            return str(f.locate())
    return ctypes.util.find_library("mkl_rt")


@functools.lru_cache(maxsize=1)
def _mkl_rt() -> tuple[ctypes.CDLL, type]:
    """MKL loaded once, with its integer type (LP64 unless the process chose ILP64)."""
    lib = ctypes.CDLL(_mkl_rt_path())
    layer = lib.MKL_Set_Interface_Layer(ctypes.c_int(0))  # 0: LP64; returns the one in force
    return lib, (np.int64 if layer == 1 else np.int32)


def _pardiso_call(lib, itype, pt, iparm, phase, n, a, ia, ja, nrhs, b, x, mtype=2) -> None:
    """One call of ``pardiso`` (one factor, no message output).

    ``mtype`` is Pardiso's matrix type: 2 real symmetric positive definite,
    -2 real symmetric indefinite.
    """
    ct = ctypes.c_int64 if itype is np.int64 else ctypes.c_int32
    err = ct(0)
    ptr = ctypes.c_void_p

    def arr(v):
        return ptr(None) if v is None else v.ctypes.data_as(ptr)

    lib.pardiso(
        arr(pt),
        ctypes.byref(ct(1)),  # maxfct
        ctypes.byref(ct(1)),  # mnum
        ctypes.byref(ct(mtype)),
        ctypes.byref(ct(phase)),
        ctypes.byref(ct(n)),
        arr(a),
        arr(ia),
        arr(ja),
        ptr(None),  # perm
        ctypes.byref(ct(nrhs)),
        arr(iparm),
        ctypes.byref(ct(0)),  # msglvl
        arr(b),
        arr(x),
        ctypes.byref(err),
    )
    if err.value != 0:
        raise _PardisoError(phase, int(err.value))


def _pardiso_release(lib, itype, pt, iparm, n, mtype=2) -> None:
    """Free Pardiso's memory for ``pt`` (phase -1)."""
    try:
        _pardiso_call(lib, itype, pt, iparm, -1, n, None, None, None, 1, None, None, mtype)
    except _PardisoError:  # nothing left to free
        pass


def _upper(A: sp.spmatrix) -> sp.csr_matrix:
    """The upper triangle of the symmetric ``A`` (m, m) as Pardiso reads it: CSR, sorted
    columns, every diagonal entry stored (zero where ``A`` has none: a missing one is an
    error) and duplicates summed."""
    T = sp.triu(sp.coo_matrix(A), format="coo")
    d = np.arange(A.shape[0])
    U = sp.coo_matrix(
        (np.r_[T.data, np.zeros(d.size)], (np.r_[T.row, d], np.r_[T.col, d])), shape=A.shape
    ).tocsr()
    U.sort_indices()
    return U


def _is_upper(A: sp.spmatrix) -> bool:
    """Whether ``A`` is already :func:`_upper`'s form: CSR, sorted and without duplicates,
    every row starting with its diagonal entry (so nothing lies below it)."""
    if not sp.isspmatrix_csr(A) or not A.has_canonical_format:
        return False
    m = A.shape[0]
    if A.shape != (m, m) or not np.all(np.diff(A.indptr) > 0):
        return False
    return bool(np.array_equal(A.indices[A.indptr[:-1]], np.arange(m)))


def _canonical(A: sp.csr_matrix) -> sp.csr_matrix:
    """``A`` itself when its columns are sorted without duplicates, else a canonical copy."""
    if A.has_canonical_format:
        return A
    A = A.copy()
    A.sum_duplicates()
    return A


def augmented_upper(S: sp.csr_matrix, Kt: sp.csr_matrix, d: np.ndarray) -> sp.csr_matrix:
    """The upper triangle of ``[[S, Kt], [Ktᵀ, diag(d)]]`` in :func:`_upper`'s form.

    Placed directly instead of assembling the whole matrix and cutting it:
    row ``i < m`` holds ``S``'s entries from its diagonal on, then ``Kt``'s
    row ``i`` (columns ``m + j``); row ``m + j`` holds ``d[j]``. The same
    arrays as :func:`_upper` of the assembled matrix when every diagonal
    entry of ``S`` is stored (:func:`_is_upper` is then true of the result;
    :class:`_Pardiso` converts it otherwise); at 100k guest vertices
    0.08 s against 0.52 s.

    Parameters
    ----------
    S : scipy.sparse.csr_matrix, shape (m, m)
        Symmetric.
    Kt : scipy.sparse.csr_matrix, shape (m, r)
    d : ndarray, shape (r,)

    Returns
    -------
    scipy.sparse.csr_matrix, shape (m + r, m + r)
    """
    S, Kt = _canonical(S), _canonical(Kt)
    m, r = S.shape[0], len(d)
    rows = np.repeat(np.arange(m), np.diff(S.indptr))
    keep = S.indices >= rows
    s_rows = rows[keep]
    del rows
    s_count = np.bincount(s_rows, minlength=m)
    k_count = np.diff(Kt.indptr)
    total = int(s_count.sum() + Kt.nnz + r)
    # the index type scipy keeps (and LP64 Pardiso reads): no copy of the largest arrays
    index = get_index_dtype(maxval=max(total, m + r))
    indptr = np.zeros(m + r + 1, dtype=index)
    np.cumsum(np.r_[s_count + k_count, np.ones(r, dtype=np.int64)], out=indptr[1:])
    data = np.empty(total)
    indices = np.empty(total, dtype=index)
    # S's kept entries first in their row, in their order
    first = np.cumsum(s_count) - s_count
    at = indptr[s_rows] + np.arange(len(s_rows)) - first[s_rows]
    data[at] = S.data[keep]
    indices[at] = S.indices[keep]
    del at, s_rows, keep, first
    # then Kt's row, its columns past S's
    k_rows = np.repeat(np.arange(m), k_count)
    at = indptr[k_rows] + s_count[k_rows] + np.arange(Kt.nnz) - Kt.indptr[k_rows]
    data[at] = Kt.data
    indices[at] = m + Kt.indices
    del at, k_rows
    data[indptr[m:-1]] = d
    indices[indptr[m:-1]] = m + np.arange(r)
    U = sp.csr_matrix((data, indices, indptr), shape=(m + r, m + r))
    # sorted and without duplicates as placed (S and Kt canonical, d one per row)
    U.has_canonical_format = True
    return U


class _Pardiso:
    """Supernodal factorization of a symmetric matrix with MKL Pardiso (METIS ordering).

    Parameters
    ----------
    A : sparse matrix, shape (m, m)
        Symmetric; only its upper triangle is read. A CSR matrix that is
        already that triangle as Pardiso reads it (sorted columns, every row
        starting at its stored diagonal: :func:`augmented_upper`'s) is
        passed on without a copy.
    indefinite : bool
        ``False``: positive definite, a Cholesky factorization (Pardiso's
        ``mtype=2``). ``True``: indefinite, an LDLᵀ factorization with
        Bunch–Kaufman pivoting inside the supernodes (``mtype=-2``); a pivot
        smaller than 1e-8 of the largest is perturbed to that size
        (``iparm[9]=8``) and each back-solve is then refined by up to two
        steps of iterative refinement (``iparm[7]=0``, Pardiso's default).

    Attributes
    ----------
    perturbed : int
        Pivots Pardiso perturbed (``iparm[13]``; 0 for a quasi-definite matrix
        ``[[S, Kᵀ], [K, −D]]`` with ``S`` and ``D`` positive definite, which
        has an LDLᵀ factorization in any order).
    """

    def __init__(self, A: sp.spmatrix, indefinite: bool = False):
        self.lib, self.itype = _mkl_rt()
        self.mtype = -2 if indefinite else 2
        U = A if _is_upper(A) else _upper(A)
        if self.itype is np.int32 and max(U.nnz, U.shape[0]) > _LP64_MAX:
            # the indices would wrap when cast to Pardiso's 32-bit integers
            raise SolveError(
                f"the system to factor has {U.nnz:,} stored entries, more than MKL Pardiso's "
                f"32-bit (LP64) indices address ({_LP64_MAX:,}); join a coarser guest "
                "(igljoin.resample) or use linear_solver='cholespy'"
            )
        self.n = U.shape[0]
        self.a = np.ascontiguousarray(U.data, dtype=np.float64)
        self.ia = np.ascontiguousarray(U.indptr, dtype=self.itype)
        self.ja = np.ascontiguousarray(U.indices, dtype=self.itype)
        self.pt = np.zeros(64, dtype=np.int64)  # Pardiso's handle: 64 pointers
        self.iparm = np.zeros(64, dtype=self.itype)
        self.iparm[0] = 1  # the iparm given here, not the defaults
        self.iparm[1] = 2  # METIS nested-dissection ordering
        self.iparm[17] = -1  # report the factor's nonzeros (read by pipelines/factor_study.py)
        self.iparm[34] = 1  # zero-based indices
        if indefinite:
            self.iparm[7] = 0  # up to two refinement steps, where a pivot was perturbed
            self.iparm[9] = 8  # perturb pivots below 1e-8 (Pardiso's default for mtype -2)
        one = np.zeros(1)
        args = (self.lib, self.itype, self.pt, self.iparm)
        weakref.finalize(self, _pardiso_release, *args, self.n, self.mtype)
        _pardiso_call(*args, 12, self.n, self.a, self.ia, self.ja, 1, one, one.copy(), self.mtype)
        self.perturbed = int(self.iparm[13])

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``A⁻¹ b`` for ``b`` of shape (m, k); returns shape (m, k)."""
        k = b.shape[1]
        bt = np.ascontiguousarray(b.T)  # column after column, as Pardiso reads them
        xt = np.empty_like(bt)
        # the back-solve on one thread (module doc)
        before = self.lib.MKL_Set_Num_Threads_Local(ctypes.c_int(1))
        try:
            _pardiso_call(
                self.lib,
                self.itype,
                self.pt,
                self.iparm,
                33,
                self.n,
                self.a,
                self.ia,
                self.ja,
                k,
                bt,
                xt,
                self.mtype,
            )
        finally:
            self.lib.MKL_Set_Num_Threads_Local(ctypes.c_int(before))
        return xt.T  # a view; the callers copy what they keep


class _FixedRows:
    """What the factored forms share: the free / fixed split and the solve with fixed rows.

    A subclass sets :attr:`n`, :attr:`free` and :attr:`fixed` (from
    :meth:`_blocks`) and provides ``solve_free`` and ``coupled``.
    """

    @staticmethod
    def _blocks(M: sp.spmatrix, fixed: np.ndarray) -> tuple:
        """The fixed and free rows of ``M`` (n, n) and its free–free and free–fixed blocks.

        Returns
        -------
        fixed : ndarray of int64, shape (b,)
        free : ndarray of int64, shape (n - b,)
            The rows not in ``fixed``, ascending.
        Mff, Mfb : scipy.sparse.csr_matrix, shapes (n - b, n - b) and (n - b, b)
        """
        fixed = np.asarray(fixed, dtype=np.int64)
        mask = np.ones(M.shape[0], dtype=bool)
        mask[fixed] = False
        free = np.flatnonzero(mask)
        rows = M[free]
        return fixed, free, sp.csr_matrix(rows[:, free]), sp.csr_matrix(rows[:, fixed])

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
        X = np.empty((self.n, B.shape[1]))
        X[self.fixed] = bc
        if not self.free.size:
            return X
        X[self.free] = self.solve_free(B[self.free] - self.coupled(bc))
        return X


class FixedQuadratic(_FixedRows):
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
        Q = sp.csr_matrix(Q)
        n = self.n = Q.shape[0]
        self.fixed, self.free, self.Qff, self.Qfb = self._blocks(Q, fixed)
        self.backend = resolve_backend(backend, self.Qff.nnz)
        if not self.free.size:
            return
        FixedQuadratic.made += 1
        if self.backend == "igl":
            self._data = igl.min_quad_with_fixed_data()
            try:
                ok = igl.min_quad_with_fixed_precompute(
                    sp.csc_matrix(Q), self.fixed, sp.csc_matrix((0, n)), True, self._data
                )
            except RuntimeError:  # libigl raises on some singular systems, returns False on others
                ok = False
            if ok is False:
                raise SolveError(_NOT_FACTORED)
        elif self.backend == "pardiso":
            try:
                self._pardiso = _Pardiso(self.Qff)
            except _PardisoError as exc:
                if exc.code in (-4, -7):
                    raise SolveError(_NOT_FACTORED) from exc
                raise SolveError(
                    f"{exc}; the deformation system could not be factored with "
                    "linear_solver='pardiso': use linear_solver='cholespy' or 'igl'"
                ) from exc
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
        if self.backend != "igl":
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
        if self.backend == "pardiso":
            return np.ascontiguousarray(self._pardiso.solve(b))
        B = np.zeros((self.n, b.shape[1]))
        B[self.free] = -b
        X = igl.min_quad_with_fixed_solve(
            self._data, B, np.zeros((len(self.fixed), b.shape[1])), np.zeros((0, b.shape[1]))
        )
        return np.asarray(X)[self.free]

    def coupled(self, bc: np.ndarray) -> np.ndarray:
        """The fixed rows' part of the free rows' right-hand side, ``Q_fb bc`` (n_free, k)."""
        return self.Qfb @ bc

    def solve(self, B: np.ndarray, bc: np.ndarray) -> np.ndarray:
        """Minimiser of ``½ xᵀ Q x − xᵀ B`` with ``x[fixed] = bc`` (see :class:`_FixedRows`)."""
        if self.backend == "igl" and self.free.size:
            B = np.asarray(B, dtype=np.float64)
            bc = np.asarray(bc, dtype=np.float64)
            return np.asarray(
                igl.min_quad_with_fixed_solve(self._data, -B, bc, np.zeros((0, B.shape[1])))
            )
        return super().solve(B, bc)


class AugmentedQuadratic(_FixedRows):
    """A factored ``Q = S + c Kᵀ W K`` with fixed rows, without forming ``Kᵀ W K``.

    When the rows of ``K`` are long (each couples many vertices), ``Kᵀ W K``
    is a dense block of ``Q``; the augmented system

    ``[[S_ff, K_fᵀ], [K_f, −(c W)⁻¹]] [x; y] = [b; 0]``

    has one extra unknown ``y = c W K_f x`` per row of ``K`` and no dense
    block, and eliminating ``y`` gives ``(S_ff + c K_fᵀ W K_f) x = b``: the
    same ``x``. It is symmetric indefinite (quasi-definite when ``S_ff`` is
    positive definite) and factored by MKL Pardiso's LDLᵀ (``mtype=-2``).
    Rows of zero weight contribute nothing and are left out.

    The same interface as :class:`FixedQuadratic` (``solve_free``,
    ``solve``, ``free``, ``fixed``, ``backend``); ``Qff`` and ``Qfb`` are
    not formed (``matvec`` applies ``Q_ff``).

    Parameters
    ----------
    S : sparse matrix, shape (n, n)
        The rest of ``Q``, positive definite on the free rows.
    K : sparse matrix, shape (r, n)
    weights : ndarray, shape (r,)
        ``W``'s diagonal, non-negative.
    c : float
        Positive scale of ``Kᵀ W K`` in ``Q``.
    fixed : ndarray of int64, shape (b,)

    Raises
    ------
    SolveError
        ``Q_ff`` is singular (a part of the guest not held by any term).
    """

    #: Largest relative residual ``‖Q_ff x − b‖ / ‖b‖`` of the probe solve made at
    #: construction; above it the factorization is taken as failed (a singular
    #: ``Q_ff`` whose zero pivots Pardiso perturbed). Measured: 1e-15 to 1e-13.
    PROBE_RESIDUAL = 1e-8

    def __init__(
        self, S: sp.spmatrix, K: sp.spmatrix, weights: np.ndarray, c: float, fixed: np.ndarray
    ):
        S = sp.csr_matrix(S)
        fixed, free, Sff, Sfb = self._blocks(S, fixed)
        weights = np.asarray(weights, dtype=np.float64)
        keep = np.flatnonzero(weights > 0.0)
        Kc = sp.csc_matrix(sp.csr_matrix(K)[keep])
        Kb = sp.csr_matrix(Kc[:, fixed])
        # K_f is kept only as K_fᵀ (K_f is its transposed view, with the same sums:
        # K_f's rows have ascending columns, the order K_fᵀ's columns are read in); the
        # rows of positive weight let go before the factorization (at 1M guest vertices
        # 0.31 GB each)
        Kft = sp.csr_matrix(Kc[:, free].T)
        del Kc
        self._set_parts(
            n=S.shape[0],
            fixed=fixed,
            free=free,
            Sff=Sff,
            Sfb=Sfb,
            Kb=Kb,
            Kft=Kft,
            cw=float(c) * weights[keep],
        )
        if not self.free.size:
            return
        FixedQuadratic.made += 1
        self._factor_augmented(augmented_upper(self.Sff, self.Kft, -1.0 / self.cw))

    def _set_parts(self, *, n, fixed, free, Sff, Sfb, Kb, Kft, cw) -> None:
        """Set every field but the factorization: the one place they are set.

        Every constructor (a subclass's too) sets them here, so that none
        misses a field another sets.

        Parameters
        ----------
        n : int
            Unknowns, free and fixed.
        fixed : ndarray of int64, shape (b,)
        free : ndarray of int64, shape (n - b,)
        Sff, Sfb : sparse matrices, shapes (n - b, n - b) and (n - b, b)
            ``S``'s free–free and free–fixed blocks.
        Kb : sparse matrix, shape (r, b)
            The rows of ``K`` of positive weight on the fixed columns.
        Kft : sparse matrix, shape (n - b, r)
            ``K_fᵀ``: those rows on the free columns, transposed (:attr:`Kf` is its
            transposed view).
        cw : ndarray, shape (r,)
            ``c W``'s diagonal on those rows.
        """
        self.n, self.fixed, self.free = n, fixed, free
        self.backend = "pardiso"
        self.Sff, self.Sfb = Sff, Sfb
        self.Kb, self.Kft = Kb, Kft
        self.cw = cw

    @property
    def Kf(self) -> sp.spmatrix:
        """``K_f``, shape (r, n - b): the rows of ``K`` of positive weight on the free
        columns, as :attr:`Kft`'s transposed view (no copy)."""
        return self.Kft.T

    def _factor_augmented(self, A: sp.spmatrix) -> None:
        """Factor the augmented matrix ``A`` with Pardiso's LDLᵀ and check it by a probe solve.

        The probe solves ``Q_ff x = 1`` (through ``A``); a result that is not
        finite or leaves a relative residual above :attr:`PROBE_RESIDUAL` is
        a failed factorization. Both failures raise ``SolveError`` with
        :meth:`_refused`'s and :meth:`_unsound`'s messages.

        Parameters
        ----------
        A : sparse matrix, shape (n_free + r, n_free + r)
            ``[[S_ff, K_fᵀ], [K_f, −(c W)⁻¹]]``; only its upper triangle is read
            (the triangle alone, :func:`augmented_upper`'s, is factored
            without a copy).
        """
        try:
            self._pardiso = _Pardiso(A, indefinite=True)
        except _PardisoError as exc:
            raise SolveError(self._refused(exc)) from exc
        probe = np.ones((self.free.size, 1))
        x = self.solve_free(probe)
        if not np.isfinite(x).all() or self.residual(x, probe) > self.PROBE_RESIDUAL:
            raise SolveError(self._unsound(self._pardiso.perturbed))

    def _refused(self, exc: Exception) -> str:
        """The message when Pardiso reports the error ``exc`` while factoring."""
        return (
            f"{exc}; the deformation system could not be factored as an augmented "
            "system: use linear_solver='cholespy' or 'igl'"
        )

    def _unsound(self, perturbed: int) -> str:
        """The message when the probe solve fails, ``perturbed`` pivots perturbed."""
        return f"{_NOT_FACTORED} ({perturbed} pivots of the augmented system were perturbed)"

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``Q_ff x`` for ``x`` of shape (n_free, k), without ``Q_ff``."""
        return self.Sff @ x + self.Kft @ (self.cw[:, None] * (self.Kf @ x))

    def residual(self, x: np.ndarray, b: np.ndarray) -> float:
        """Relative residual ``‖Q_ff x − b‖ / ‖b‖`` (Frobenius) of a solve of ``b`` (n_free, k)."""
        return float(np.linalg.norm(self.matvec(x) - b) / max(np.linalg.norm(b), 1e-300))

    def solve_free(self, b: np.ndarray) -> np.ndarray:
        """``Q_ff⁻¹ b`` for ``b`` of shape (n_free, k); returns shape (n_free, k)."""
        b = np.ascontiguousarray(b, dtype=np.float64)
        if not self.free.size:
            return np.zeros_like(b)
        rhs = np.zeros((self.free.size + self.cw.size, b.shape[1]))
        rhs[: self.free.size] = b
        return np.ascontiguousarray(self._pardiso.solve(rhs)[: self.free.size])

    def coupled(self, bc: np.ndarray) -> np.ndarray:
        """The fixed rows' part of the right-hand side, ``S_fb bc + c K_fᵀ W (K_b bc)``.

        Products with the factors only (shape (n_free, k)).
        """
        return self.Sfb @ bc + self.Kft @ (self.cw[:, None] * (self.Kb @ bc))
