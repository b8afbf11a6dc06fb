"""Compiled (numba) projection of the factored Gauss–Newton model onto a coarse space.

The two-level preconditioner (:mod:`igljoin.twolevel`) needs
``A_c = Σ s (J A)ᵀ diag(w) (J A)`` for the stacked factors ``J`` of
:func:`igljoin.newton.gauss_newton_factors` and the clusters' motions ``A``
(every free vertex ``v`` carries one dense block ``B_v`` of shape (3, w) in
its cluster's ``w`` columns). The sparsity patterns of ``J``, of ``J A``
and of ``A_c`` depend on the mesh and the clusters only, not on the
positions: :func:`row_clusters` and :func:`block_pattern` find them once,
and :func:`project` recomputes the values of ``A_c``'s (w, w) blocks at a
rebuild, one pass over ``J``'s rows with no sparse product.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["row_clusters", "block_pattern", "project", "motion_rows", "rotation_factor"]


@nb.njit(cache=True, inline="always")
def _position(out, start, stop, c):
    """Where ``c`` is, or would go, in the ascending ``out[start:stop]`` (binary search)."""
    lo, hi = start, stop
    while lo < hi:
        mid = (lo + hi) // 2
        if out[mid] < c:
            lo = mid + 1
        else:
            hi = mid
    return lo


@nb.njit(cache=True, inline="always")
def _add_row_motions(JA, r, indptr, indices, data, slot, B):
    """Add row ``r`` of ``J`` times the motions ``B`` into ``JA`` (q, w): one row per cluster."""
    w = B.shape[2]
    for p in range(indptr[r], indptr[r + 1]):
        s = slot[p]
        if s < 0:
            continue
        v = indices[p] // 3
        c = indices[p] - 3 * v
        x = data[p]
        for k in range(w):
            JA[s, k] += x * B[v, c, k]


@nb.njit(cache=True)
def row_clusters(indptr, indices, labels, stride=3):
    """The clusters every row of ``J`` touches and where each entry lands among them.

    Parameters
    ----------
    indptr, indices : ndarray of int
        ``J``'s CSR pattern, shape (r + 1,) and (nnz,); columns ``3 v + c``
        (``stride`` 3) or vertices ``v`` (``stride`` 1, an operator ``K``).
    labels : ndarray of int64, shape (n,)
        Cluster of every vertex, −1 at a fixed vertex.
    stride : int
        Columns per vertex.

    Returns
    -------
    ptr : ndarray of int64, shape (r + 1,)
        Row ``i``'s clusters are ``clusters[ptr[i]:ptr[i + 1]]`` (ascending).
    clusters : ndarray of int64
    slot : ndarray of int32, shape (nnz,)
        Position of each entry's cluster within its row's list, −1 at a
        fixed vertex.
    """
    rows = len(indptr) - 1
    ptr = np.zeros(rows + 1, dtype=np.int64)
    slot = np.full(len(indices), -1, dtype=np.int32)
    out = np.empty(len(indices), dtype=np.int64)
    q = 0
    for r in range(rows):
        start = q
        for p in range(indptr[r], indptr[r + 1]):
            c = labels[indices[p] // stride]
            if c < 0:
                continue
            # binary search in the row's ascending list, then insertion
            lo = _position(out, start, q, c)
            if lo == q or out[lo] != c:
                for t in range(q, lo, -1):
                    out[t] = out[t - 1]
                out[lo] = c
                q += 1
        ptr[r + 1] = q
        for p in range(indptr[r], indptr[r + 1]):
            c = labels[indices[p] // stride]
            if c < 0:
                continue
            slot[p] = _position(out, start, q, c) - start
    return ptr, out[:q].copy(), slot


def block_pattern(rows: list, a: int):
    """The (w, w) blocks of ``A_c`` the rows of all factors reach.

    Block ``(k, l)`` is reached when some row touches both clusters ``k``
    and ``l``: the pattern of ``Tᵀ T`` for the rows' cluster incidence
    ``T`` (one row per factor row, one column per cluster). Found by a
    sparse product, in memory proportional to the blocks and to ``T`` —
    never to the rows' cluster pairs, which a band row reaching hundreds of
    clusters counts in tens of thousands.

    Parameters
    ----------
    rows : list of (ndarray, ndarray)
        Every factor's ``(ptr, clusters)`` (:func:`row_clusters`).
    a : int
        Number of clusters.

    Returns
    -------
    indptr, indices : ndarray of int64, shape (a + 1,) and (b,)
        Block-CSR pattern of ``A_c``, both triangles (ascending columns per
        block row).
    lower, upper : ndarray of int64
        Every block below the diagonal and the block above it that is its
        transpose.
    """
    import scipy.sparse as sp

    if rows:
        ptr = np.concatenate([p[1:] - p[0] + off for p, off in _offsets(rows)])
        ptr = np.r_[0, ptr]
        members = np.concatenate([c for _, c in rows])
    else:
        ptr, members = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    T = sp.csr_matrix(
        (np.ones(len(members), dtype=np.float32), members, ptr), shape=(len(ptr) - 1, a)
    )
    P = sp.csr_matrix(T.T @ T)
    P.sort_indices()
    indptr = P.indptr.astype(np.int64)
    fcol = P.indices.astype(np.int64)
    frow = np.repeat(np.arange(a, dtype=np.int64), np.diff(indptr))
    lower = np.flatnonzero(frow > fcol)
    # the transpose of block (k, l), k > l: block (l, k), found in block row l
    full = frow * a + fcol
    upper = np.searchsorted(full, fcol[lower] * a + frow[lower]).astype(np.int64)
    return indptr, fcol, lower, upper


def _offsets(rows: list):
    """Every factor's ``ptr`` with the entries before it: its rows' starts in the stack."""
    off = 0
    for ptr, members in rows:
        yield ptr, off
        off += len(members)


@nb.njit(cache=True)
def project(indptr, indices, data, weights, ptr, clusters, slot, bptr, bcols, B, blocks):
    """Add ``Σ_r w_r (J_r A)ᵀ (J_r A)`` into ``blocks`` (b, w, w): the blocks on and above
    the diagonal only (the caller copies the transposes below it).

    Parameters
    ----------
    indptr, indices, data : ndarray
        ``J`` in CSR form, shape (r + 1,), (nnz,), (nnz,); columns ``3 v + c``.
    weights : ndarray, shape (r,)
        Signed row weights ``s w``.
    ptr, clusters, slot : ndarray
        From :func:`row_clusters`.
    bptr, bcols : ndarray of int64
        ``A_c``'s block pattern (:func:`block_pattern`); the block of a
        row's cluster pair is found in it by bisection.
    B : ndarray, shape (n, 3, w)
        Every vertex's motions (any values at a fixed vertex: never read).
    blocks : ndarray, shape (b, w, w)
        Accumulated into.
    """
    w = B.shape[2]
    most = 0
    for r in range(len(ptr) - 1):
        most = max(most, ptr[r + 1] - ptr[r])
    JA = np.zeros((most, w))
    for r in range(len(ptr) - 1):
        q = ptr[r + 1] - ptr[r]
        wr = weights[r]
        if q == 0 or wr == 0.0:
            continue
        JA[:q, :] = 0.0
        _add_row_motions(JA, r, indptr, indices, data, slot, B)
        first = ptr[r]
        for i in range(q):
            # the row's clusters ascend: each pair's block lies past the one before
            lo = bptr[clusters[first + i]]
            end = bptr[clusters[first + i] + 1]
            for j in range(i, q):
                b = _position(bcols, lo, end, clusters[first + j])
                lo = b + 1
                for k in range(w):
                    y = wr * JA[i, k]
                    if y != 0.0:
                        for m in range(w):
                            blocks[b, k, m] += y * JA[j, m]


@nb.njit(cache=True, inline="always")
def _add_cross(out, c, s):
    """``out += s [c]×`` for a (3, 3) ``out``."""
    out[0, 1] -= s * c[2]
    out[0, 2] += s * c[1]
    out[1, 0] += s * c[2]
    out[1, 2] -= s * c[0]
    out[2, 0] -= s * c[1]
    out[2, 1] += s * c[0]


@nb.njit(cache=True, inline="always")
def _add_inertia(out, c, s):
    """``out += s (|c|² I − c cᵀ)`` for a (3, 3) ``out``."""
    q = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    for a in range(3):
        for b in range(3):
            out[a, b] -= s * c[a] * c[b]
        out[a, a] += s * q


@nb.njit(cache=True)
def _inverse_cholesky(S, Z):
    """``Z`` (3, 3, lower) with ``Z Zᵀ = S⁻¹`` for a symmetric positive definite ``S``."""
    a00 = S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1]
    a01 = S[0, 2] * S[2, 1] - S[0, 1] * S[2, 2]
    a02 = S[0, 1] * S[1, 2] - S[0, 2] * S[1, 1]
    a11 = S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]
    a12 = S[0, 2] * S[1, 0] - S[0, 0] * S[1, 2]
    a22 = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    det = (
        S[0, 0] * a00
        + S[0, 1] * (S[1, 2] * S[2, 0] - S[1, 0] * S[2, 2])
        + S[0, 2] * (S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0])
    )
    t00, t10, t20, t11, t21, t22 = a00 / det, a01 / det, a02 / det, a11 / det, a12 / det, a22 / det
    Z[0, 0] = np.sqrt(t00)
    Z[1, 0] = t10 / Z[0, 0]
    Z[2, 0] = t20 / Z[0, 0]
    Z[1, 1] = np.sqrt(t11 - Z[1, 0] * Z[1, 0])
    Z[2, 1] = (t21 - Z[2, 0] * Z[1, 0]) / Z[1, 1]
    Z[2, 2] = np.sqrt(t22 - Z[2, 0] * Z[2, 0] - Z[2, 1] * Z[2, 1])


@nb.njit(cache=True)
def rotation_factor(indptr, indices, ldata, R, delta, E, rest, own_own, own_other, w, mu):
    """Values of the rotations' elimination factor ``C`` (``Σ_i M_i S_i⁻¹ M_iᵀ = CᵀC``).

    The same matrix as :func:`igljoin.newton.gauss_newton_factors`'s numpy
    reference: the Laplacian row of vertex ``i`` (coefficients ``L[i, v]``,
    target ``c = R_i δ_i``) and its one-ring edge rows (weight ``w μ``,
    targets ``±R_o e₀``) give ``M_i`` (a (3, 3) block per entry of ``L``'s
    row ``i``) and ``S_i``; row ``3 i + c`` of ``C`` holds ``(M_p Z_i)[a, c]``
    at column ``3 v + a`` with ``Z_i`` the Cholesky factor of ``S_i⁻¹``.

    Parameters
    ----------
    indptr, indices, ldata : ndarray
        ``L`` in CSR form with sorted columns, shape (n + 1,), (p,), (p,).
    R : ndarray, shape (n, 3, 3)
        Fitted rotations.
    delta : ndarray, shape (n, 3)
        Rest Laplacian coordinates ``δ``.
    E : ndarray of int64, shape (e, 2)
    rest : ndarray, shape (e, 3)
        Rest edge vectors ``x₀[E[:, 0]] − x₀[E[:, 1]]``.
    own_own, own_other : ndarray of int64, shape (2, e)
        Entry of ``L`` at ``(o, o)`` and at ``(o, t)`` for the edge's end
        ``o = E[:, k]`` owning the row and its other end ``t``.
    w, mu : float
        The term's weight and the rotation regularisation.

    Returns
    -------
    ndarray, shape (9 p,)
        ``C``'s values in CSR order: rows ``3 i + c``, each the entries ``p``
        of ``L``'s row ``i`` times columns ``a`` = 0, 1, 2.
    """
    n = len(indptr) - 1
    M = np.zeros((len(indices), 3, 3))
    S = np.zeros((n, 3, 3))
    c = np.empty(3)
    for i in range(n):
        for a in range(3):
            c[a] = R[i, a, 0] * delta[i, 0] + R[i, a, 1] * delta[i, 1] + R[i, a, 2] * delta[i, 2]
        for p in range(indptr[i], indptr[i + 1]):
            _add_cross(M[p], c, w * ldata[p])
        _add_inertia(S[i], c, w)
    for k in range(2):
        sign = 1.0 if k == 0 else -1.0
        for e in range(len(E)):
            o = E[e, k]
            for a in range(3):
                c[a] = sign * (
                    R[o, a, 0] * rest[e, 0] + R[o, a, 1] * rest[e, 1] + R[o, a, 2] * rest[e, 2]
                )
            _add_cross(M[own_own[k, e]], c, w * mu)
            _add_cross(M[own_other[k, e]], c, -w * mu)
            _add_inertia(S[o], c, w * mu)
    out = np.empty(9 * len(indices))
    Z = np.zeros((3, 3))
    for i in range(n):
        _inverse_cholesky(S[i], Z)
        start, count = indptr[i], indptr[i + 1] - indptr[i]
        for p in range(start, indptr[i + 1]):
            N = M[p] @ Z
            for cc in range(3):
                base = 9 * start + 3 * cc * count + 3 * (p - start)
                for a in range(3):
                    out[base + a] = N[a, cc]
    return out


@nb.njit(cache=True)
def motion_rows(indptr, indices, data, ptr, slot, B):
    """The values of ``J A``: every row of ``J`` on its clusters' motions.

    Row ``r`` of ``J A`` has ``w`` entries per cluster it touches, at
    columns ``w k .. w k + w − 1`` for its clusters ``k`` (ascending): CSR
    with ``indptr = w ptr``.

    Parameters
    ----------
    indptr, indices, data : ndarray
        ``J`` in CSR form, shape (r + 1,), (nnz,), (nnz,); columns ``3 v + c``.
    ptr, slot : ndarray
        From :func:`row_clusters`.
    B : ndarray, shape (n, 3, w)
        Every vertex's motions (never read at a fixed vertex).

    Returns
    -------
    ndarray, shape (w ptr[-1],)
    """
    w = B.shape[2]
    out = np.zeros(w * ptr[-1])
    rows = out.reshape((ptr[-1], w))
    for r in range(len(ptr) - 1):
        _add_row_motions(rows[ptr[r] : ptr[r + 1]], r, indptr, indices, data, slot, B)
    return out
