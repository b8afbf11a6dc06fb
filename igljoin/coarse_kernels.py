"""Compiled (numba) projection of the factored Gauss–Newton model onto a coarse space.

The two-level preconditioner (:mod:`igljoin.twolevel`) needs
``A_c = Σ s (J A)ᵀ diag(w) (J A)`` for the factor rows ``J`` of
:func:`igljoin.newton.factor_rows` (rows ``K_r ⊗ d`` of the terms'
operators, and the rotations' factor on the Laplacian's pattern) and the
clusters' motions ``A`` (every free vertex ``v`` carries one dense block
``B_v`` of shape (3, w) in its cluster's ``w`` columns). The sparsity
patterns of ``J A`` and of ``A_c`` depend on the mesh and the clusters
only, not on the positions: :func:`row_clusters` (on the operators) and
:func:`block_pattern` find them once, and :func:`project_rows` and
:func:`project_rotation` recompute the values of ``A_c``'s (w, w) blocks at
a rebuild, one pass over the operators' rows without forming ``J``.
:func:`edge_lengths` weighs the graph the clusters are grown on.
:func:`restrict` and :func:`prolong` apply ``Aᵀ`` and ``A`` from the blocks,
without holding the GIL (the additive form runs them, with the coarse solve,
on a thread beside the fine back-solve).
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = [
    "edge_lengths",
    "row_clusters",
    "block_pattern",
    "project_rows",
    "project_rotation",
    "motion_rows_of",
    "rotation_factor",
    "restrict",
    "prolong",
]


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


@nb.njit(cache=True)
def edge_lengths(indptr, indices, X):
    """A graph's off-diagonal pattern with every entry's length ``|x_i − x_j|``.

    Parameters
    ----------
    indptr, indices : ndarray of int
        The graph's CSR pattern, shape (m + 1,) and (nnz,).
    X : ndarray, shape (m, 3)
        Positions.

    Returns
    -------
    ptr : ndarray of int64, shape (m + 1,)
    cols : ndarray of int64, shape (k,)
        The pattern without its diagonal, in the graph's order.
    length : ndarray, shape (k,)
        ``|x_i − x_j|`` plus 1e-300 (a zero-length edge stays an edge).
    """
    m = len(indptr) - 1
    ptr = np.zeros(m + 1, dtype=np.int64)
    cols = np.empty(len(indices), dtype=np.int64)
    length = np.empty(len(indices))
    q = 0
    for i in range(m):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if j == i:
                continue
            a = X[i, 0] - X[j, 0]
            b = X[i, 1] - X[j, 1]
            c = X[i, 2] - X[j, 2]
            cols[q] = j
            length[q] = np.sqrt(a * a + b * b + c * c) + 1e-300
            q += 1
        ptr[i + 1] = q
    return ptr, cols[:q].copy(), length[:q].copy()


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

    The factor of :func:`igljoin.newton.gauss_newton_factors` with the minus
    sign (tests/test_newton.py checks it against a numpy transcription of
    the model): the Laplacian row of vertex ``i`` (coefficients ``L[i, v]``,
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


@nb.njit(cache=True, inline="always")
def _pair_blocks(pairs, first, q, clusters, bptr, bcols):
    """The block of ``A_c`` of every cluster pair ``i ≤ j`` of a row (``q`` clusters).

    ``pairs[i * q + j]`` (``j ≥ i``) is found by bisection in the block row
    of the row's ``i``-th cluster; the clusters ascend, so each pair's block
    lies past the one before.
    """
    for i in range(q):
        lo = bptr[clusters[first + i]]
        end = bptr[clusters[first + i] + 1]
        for j in range(i, q):
            b = _position(bcols, lo, end, clusters[first + j])
            pairs[i * q + j] = b
            lo = b + 1


@nb.njit(cache=True, inline="always")
def _add_pairs(blocks, pairs, JA, q, wr):
    """``blocks[b(i, j)] += wr JA[i]ᵀ JA[j]`` for the row's cluster pairs ``i ≤ j``."""
    w = JA.shape[1]
    for i in range(q):
        for j in range(i, q):
            b = pairs[i * q + j]
            for k in range(w):
                y = wr * JA[i, k]
                if y != 0.0:
                    for m in range(w):
                        blocks[b, k, m] += y * JA[j, m]


@nb.njit(cache=True)
def _row_buffers(ptr, w):
    """The most clusters a row reaches and the per-row buffers of that size.

    Returns ``(most, JA, pairs)``: ``JA`` of shape (most, w) for a row's
    ``J_r A`` and ``pairs`` of shape (most²,) for its blocks
    (:func:`_pair_blocks`), ``ptr`` being :func:`row_clusters`'s.
    """
    most = 0
    for r in range(len(ptr) - 1):
        most = max(most, ptr[r + 1] - ptr[r])
    return most, np.zeros((most, w)), np.zeros(most * most, dtype=np.int64)


@nb.njit(cache=True)
def project_rows(
    indptr, indices, data, directions, weights, ptr, clusters, slot, bptr, bcols, where, B, blocks
):
    """Add ``Σ_r Σ_d w_rd (J_rd A)ᵀ (J_rd A)`` for the rows ``J_rd = K_r ⊗ d`` into ``blocks``.

    The rows of :func:`igljoin.newton.factor_rows`, without forming them:
    for every row ``K_r`` of the operator its clusters' motions ``K_r B``
    (3 coordinates each) are summed once, and each direction ``d`` of the
    row combines them. Only the blocks on and above the diagonal are
    written (the caller copies the transposes below it).

    Parameters
    ----------
    indptr, indices, data : ndarray
        ``K`` in CSR form, shape (r + 1,), (nnz,), (nnz,); columns are vertices.
    directions : ndarray, shape (r, D, 3), or shape (0, 3, 3)
        Every row's directions; empty: the unit directions (``D = 3``).
    weights : ndarray, shape (r, D)
        Signed weights.
    ptr, clusters, slot : ndarray
        :func:`row_clusters` of ``K`` (stride 1).
    bptr, bcols : ndarray of int64
        ``A_c``'s block pattern (:func:`block_pattern`).
    where : ndarray of int64, shape (n,)
        Every vertex's row in ``B`` (read at free vertices only).
    B : ndarray, shape (m, 3, w)
        Every free vertex's motions.
    blocks : ndarray, shape (b, w, w)
        Accumulated into.
    """
    w = B.shape[2]
    unit = directions.shape[0] == 0
    most, JA, pairs = _row_buffers(ptr, w)
    KB = np.zeros((most, 3, w))
    for r in range(len(ptr) - 1):
        q = ptr[r + 1] - ptr[r]
        if q == 0:
            continue
        KB[:q] = 0.0
        for p in range(indptr[r], indptr[r + 1]):
            s = slot[p]
            if s < 0:
                continue
            v = where[indices[p]]
            x = data[p]
            for c in range(3):
                for k in range(w):
                    KB[s, c, k] += x * B[v, c, k]
        _pair_blocks(pairs, ptr[r], q, clusters, bptr, bcols)
        for d in range(weights.shape[1]):
            wr = weights[r, d]
            if wr == 0.0:
                continue
            for i in range(q):
                for k in range(w):
                    if unit:
                        JA[i, k] = KB[i, d, k]
                    else:
                        JA[i, k] = (
                            directions[r, d, 0] * KB[i, 0, k]
                            + directions[r, d, 1] * KB[i, 1, k]
                            + directions[r, d, 2] * KB[i, 2, k]
                        )
            _add_pairs(blocks, pairs, JA, q, wr)


@nb.njit(cache=True)
def project_rotation(indptr, indices, values, ptr, clusters, slot, bptr, bcols, where, B, blocks):
    """Subtract ``Σ (C_r A)ᵀ (C_r A)`` for the rotations' factor ``C`` from ``blocks``.

    ``C``'s rows ``3 i + c`` hold three values per entry ``p`` of the
    Laplacian's row ``i`` (:func:`rotation_factor`'s layout); the pattern
    is the Laplacian's, so :func:`row_clusters` of ``L`` (stride 1) serves
    all three rows of a vertex.

    Parameters
    ----------
    indptr, indices : ndarray of int64
        ``L`` in CSR form with sorted columns.
    values : ndarray, shape (9 nnz,)
        :func:`rotation_factor`.
    ptr, clusters, slot, bptr, bcols, where, B, blocks
        As :func:`project_rows`'s.
    """
    w = B.shape[2]
    _, JA, pairs = _row_buffers(ptr, w)
    for r in range(len(ptr) - 1):
        q = ptr[r + 1] - ptr[r]
        if q == 0:
            continue
        _pair_blocks(pairs, ptr[r], q, clusters, bptr, bcols)
        start, count = indptr[r], indptr[r + 1] - indptr[r]
        for cc in range(3):
            JA[:q] = 0.0
            for p in range(start, indptr[r + 1]):
                s = slot[p]
                if s < 0:
                    continue
                v = where[indices[p]]
                base = 9 * start + 3 * cc * count + 3 * (p - start)
                for a in range(3):
                    x = values[base + a]
                    for k in range(w):
                        JA[s, k] += x * B[v, a, k]
            _add_pairs(blocks, pairs, JA, q, -1.0)


@nb.njit(cache=True)
def motion_rows_of(indptr, indices, data, directions, ptr, slot, where, B):
    """The values of ``J A`` for the rows ``K_r ⊗ d`` (:func:`project_rows`'s), row-major.

    Row ``r D + d`` has ``w`` entries per cluster row ``r`` of ``K``
    touches, at columns ``w k .. w k + w − 1`` for its clusters ``k``
    (ascending).

    Parameters
    ----------
    indptr, indices, data, directions, ptr, slot, where, B
        As :func:`project_rows`'s; ``directions`` of shape (r, D, 3), or
        empty for the unit directions (``D = 3``).

    Returns
    -------
    ndarray, shape (D w ptr[-1],)
    """
    w = B.shape[2]
    unit = directions.shape[0] == 0
    D = 3 if unit else directions.shape[1]
    out = np.zeros(D * w * ptr[-1])
    at = 0
    for r in range(len(ptr) - 1):
        q = ptr[r + 1] - ptr[r]
        # one pass over the row per direction, summing (K_rp d_c) B_vc: the rows kept apart
        # are in practice the smooth join's band rows, one direction each, where a K_r B
        # summed once (as project_rows does) saves nothing; for several directions it
        # would round the values differently
        for d in range(D):
            for p in range(indptr[r], indptr[r + 1]):
                s = slot[p]
                if s < 0:
                    continue
                v = where[indices[p]]
                for c in range(3):
                    x = data[p] * ((1.0 if c == d else 0.0) if unit else directions[r, d, c])
                    if x != 0.0:
                        for k in range(w):
                            out[at + w * s + k] += x * B[v, c, k]
            at += w * q
    return out


@nb.njit(cache=True, nogil=True)  # runs beside the fine back-solve (twolevel.solve_free)
def restrict(B, labels, v, a):
    """``Aᵀ v`` for the motions ``B`` (m, 3, w) of clusters ``labels`` (m,), ``v`` (3 m,).

    Returns
    -------
    ndarray, shape (w a,)
    """
    w = B.shape[2]
    out = np.zeros(w * a)
    for i in range(B.shape[0]):
        base = w * labels[i]
        for c in range(3):
            x = v[3 * i + c]
            for k in range(w):
                out[base + k] += B[i, c, k] * x
    return out


@nb.njit(cache=True, nogil=True)
def prolong(B, labels, y):
    """``A y`` for the motions ``B`` (m, 3, w) of clusters ``labels`` (m,), ``y`` (w a,).

    Returns
    -------
    ndarray, shape (3 m,)
    """
    w = B.shape[2]
    out = np.empty(3 * B.shape[0])
    for i in range(B.shape[0]):
        base = w * labels[i]
        for c in range(3):
            x = 0.0
            for k in range(w):
                x += B[i, c, k] * y[base + k]
            out[3 * i + c] = x
    return out
