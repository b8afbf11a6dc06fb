"""Compiled local steps of the energy terms (numba).

Every iteration of the join evaluates, for the current positions, each
term's energy and half-gradient (:meth:`igljoin.terms.Term.local`). In numpy
that is a few dozen array passes, sparse products and gathers per step —
about 2 ms on a paper-sized guest, most of the iteration. The functions here
do the same work in a few loops over vertices or edges, compiled by numba
(``cache=True``: compiled once per machine, then loaded from the cache); the
rotation fit steps a block of vertices at a time through branch-free loops
that the compiler vectorises, each vertex still through exactly its own
sequence of operations.

They are exact re-statements of the numpy local steps in
:mod:`igljoin.terms`, which stay as the reference implementation: a term
built with ``compiled=False`` runs them, and the tests compare both paths
to rounding.

Layouts: positions ``X`` (n, 3); edges ``E`` (e, 2) with edge vectors
``d_e = X[E[e, 0]] − X[E[e, 1]]``; rotations (n, 3, 3); half-gradients are
*added* into a caller's (n, 3) array ``G``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = [
    "edge_vectors",
    "shape_local",
    "shape_residuals",
    "stretch_local",
    "smooth_local",
    "band_local",
    "dot",
    "join_rows",
    "step",
    "abs_max",
    "take_rows",
    "lbfgs_pair",
    "lbfgs_first_loop",
    "lbfgs_second_loop",
]

# Newton on SO(3): same constants as igljoin.rotations (step below which a rotation
# has settled, steps before the SVD decides, relative margin of the maximum condition)
_STEP_TOLERANCE = 1e-7
_MAX_STEPS = 8
_DEGENERATE = 1e-9


@nb.njit(cache=True, inline="always")
def _row_times(ptr, idx, val, X, r):  # pragma: no cover - compiled
    """Row ``r`` of a CSR matrix (``ptr``, ``idx``, ``val``) times ``X`` (n, 3): three floats."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for k in range(ptr[r], ptr[r + 1]):
        j = idx[k]
        a = val[k]
        s0 += a * X[j, 0]
        s1 += a * X[j, 1]
        s2 += a * X[j, 2]
    return s0, s1, s2


@nb.njit(cache=True, inline="always")
def _add_opposite(G, i, j, r0, r1, r2):  # pragma: no cover - compiled
    """Add ``r`` to row ``i`` of ``G`` (n, 3) and subtract it from row ``j``.

    The half-gradient of a residual of the difference ``X[i] − X[j]``.
    """
    G[i, 0] += r0
    G[i, 1] += r1
    G[i, 2] += r2
    G[j, 0] -= r0
    G[j, 1] -= r1
    G[j, 2] -= r2


@nb.njit(cache=True)
def edge_vectors(X, E):  # pragma: no cover - compiled
    """``X[E[:, 0]] − X[E[:, 1]]``, shape (e, 3)."""
    ne = E.shape[0]
    d = np.empty((ne, 3))
    for k in range(ne):
        i = E[k, 0]
        j = E[k, 1]
        d[k, 0] = X[i, 0] - X[j, 0]
        d[k, 1] = X[i, 1] - X[j, 1]
        d[k, 2] = X[i, 2] - X[j, 2]
    return d


@nb.njit(cache=True, inline="always", error_model="numpy")
def _newton_step(
    a00, a01, a02, a10, a11, a12, a20, a21, a22, r00, r01, r02, r10, r11, r12, r20, r21, r22
):  # pragma: no cover - compiled
    """One Newton step on SO(3) for ``max tr(Rᵀ A)`` from ``R``, in scalars.

    See igljoin.rotations._newton_step. Returns ``ok`` (the Hessian is
    positive definite, relative margin ``_DEGENERATE``, and the step
    finite), the step's size ``θ`` and the nine entries of the new ``R``
    (row by row); the new ``R`` is meaningful only where ``ok``. Without
    branches, so that a loop over a block of vertices stays vectorised
    (:func:`_newton_lanes`); its callers use the numpy error model, as a
    step whose ``ok`` is false may divide by zero.
    """
    # M = Rᵀ A
    m00 = r00 * a00 + r10 * a10 + r20 * a20
    m01 = r00 * a01 + r10 * a11 + r20 * a21
    m02 = r00 * a02 + r10 * a12 + r20 * a22
    m10 = r01 * a00 + r11 * a10 + r21 * a20
    m11 = r01 * a01 + r11 * a11 + r21 * a21
    m12 = r01 * a02 + r11 * a12 + r21 * a22
    m20 = r02 * a00 + r12 * a10 + r22 * a20
    m21 = r02 * a01 + r12 * a11 + r22 * a21
    m22 = r02 * a02 + r12 * a12 + r22 * a22
    s0 = m12 - m21
    s1 = m20 - m02
    s2 = m01 - m10
    tr = m00 + m11 + m22
    a = tr - m00
    d = tr - m11
    f = tr - m22
    b = -0.5 * (m01 + m10)
    c = -0.5 * (m02 + m20)
    e = -0.5 * (m12 + m21)
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + c * c02
    scale = abs(a) + abs(d) + abs(f) + 1e-300
    positive = (
        (a > _DEGENERATE * scale)
        & (c22 > _DEGENERATE * scale * scale)
        & (det > _DEGENERATE * scale * scale * scale)
    )
    inv = -1.0 / det
    w0 = (c00 * s0 + c01 * s1 + c02 * s2) * inv
    w1 = (c01 * s0 + c11 * s1 + c12 * s2) * inv
    w2 = (c02 * s0 + c12 * s1 + c22 * s2) * inv
    theta = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    # Cayley retraction of the half step (exactly orthogonal)
    w0 *= 0.5
    w1 *= 0.5
    w2 *= 0.5
    alpha = 2.0 / (1.0 + w0 * w0 + w1 * w1 + w2 * w2)
    e00 = 1.0 - alpha * (w1 * w1 + w2 * w2)
    e11 = 1.0 - alpha * (w0 * w0 + w2 * w2)
    e22 = 1.0 - alpha * (w0 * w0 + w1 * w1)
    p01 = alpha * w0 * w1
    p02 = alpha * w0 * w2
    p12 = alpha * w1 * w2
    e01 = p01 - alpha * w2
    e10 = p01 + alpha * w2
    e02 = p02 + alpha * w1
    e20 = p02 - alpha * w1
    e12 = p12 - alpha * w0
    e21 = p12 + alpha * w0
    return (
        positive & (theta < math.inf),
        theta,
        r00 * e00 + r01 * e10 + r02 * e20,
        r00 * e01 + r01 * e11 + r02 * e21,
        r00 * e02 + r01 * e12 + r02 * e22,
        r10 * e00 + r11 * e10 + r12 * e20,
        r10 * e01 + r11 * e11 + r12 * e21,
        r10 * e02 + r11 * e12 + r12 * e22,
        r20 * e00 + r21 * e10 + r22 * e20,
        r20 * e01 + r21 * e11 + r22 * e21,
        r20 * e02 + r21 * e12 + r22 * e22,
    )


@nb.njit(cache=True, error_model="numpy")
def _newton_rotation(A, R, steps):  # pragma: no cover - compiled
    """Newton on SO(3) for ``max tr(Rᵀ A)`` from ``R`` (3 × 3, updated in place).

    At most ``steps`` steps (:func:`_newton_step`). Returns whether it
    settled at a maximum (a local maximum of ``tr(Rᵀ A)`` on SO(3) is the
    global one). Works on scalars: small-array operations inside a
    per-vertex loop cost more than the arithmetic.
    """
    a00, a01, a02 = A[0, 0], A[0, 1], A[0, 2]
    a10, a11, a12 = A[1, 0], A[1, 1], A[1, 2]
    a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    settled = False
    for _ in range(steps):
        ok, theta, n00, n01, n02, n10, n11, n12, n20, n21, n22 = _newton_step(
            a00, a01, a02, a10, a11, a12, a20, a21, a22,
            r00, r01, r02, r10, r11, r12, r20, r21, r22,
        )  # fmt: skip
        if not ok:
            break
        r00, r01, r02 = n00, n01, n02
        r10, r11, r12 = n10, n11, n12
        r20, r21, r22 = n20, n21, n22
        if theta <= _STEP_TOLERANCE:
            settled = True
            break
    R[0, 0], R[0, 1], R[0, 2] = r00, r01, r02
    R[1, 0], R[1, 1], R[1, 2] = r10, r11, r12
    R[2, 0], R[2, 1], R[2, 2] = r20, r21, r22
    return settled


# The rotation fit started from hints works on blocks of _LANES vertices held in one
# buffer of rows of _LANES entries (rows _ROW_A.. the covariances, _ROW_R.. the
# rotations, then one flag row each): every loop over a block's lanes runs on one
# array without branches, which the compiler turns into vector instructions.
_LANES = 64
_ROW_A = 0
_ROW_R = 9
_ROW_ACTIVE = 18
_ROW_SETTLED = 19
_ROWS = 20


@nb.njit(cache=True, error_model="numpy")
def _newton_lanes(buf):  # pragma: no cover - compiled
    """One step of :func:`_newton_rotation` on every active lane of a block.

    ``buf`` holds ``_ROWS`` rows of ``_LANES`` entries. A lane's rotation
    changes exactly as :func:`_newton_rotation`'s would (the same
    :func:`_newton_step`); a lane whose step breaks off keeps its rotation
    and goes inactive, one whose step settles is marked settled and goes
    inactive. Inactive lanes are computed too and their results dropped.
    """
    W = _LANES
    for v in range(W):
        r00 = buf[(_ROW_R + 0) * W + v]
        r01 = buf[(_ROW_R + 1) * W + v]
        r02 = buf[(_ROW_R + 2) * W + v]
        r10 = buf[(_ROW_R + 3) * W + v]
        r11 = buf[(_ROW_R + 4) * W + v]
        r12 = buf[(_ROW_R + 5) * W + v]
        r20 = buf[(_ROW_R + 6) * W + v]
        r21 = buf[(_ROW_R + 7) * W + v]
        r22 = buf[(_ROW_R + 8) * W + v]
        ok, theta, n00, n01, n02, n10, n11, n12, n20, n21, n22 = _newton_step(
            buf[(_ROW_A + 0) * W + v], buf[(_ROW_A + 1) * W + v], buf[(_ROW_A + 2) * W + v],
            buf[(_ROW_A + 3) * W + v], buf[(_ROW_A + 4) * W + v], buf[(_ROW_A + 5) * W + v],
            buf[(_ROW_A + 6) * W + v], buf[(_ROW_A + 7) * W + v], buf[(_ROW_A + 8) * W + v],
            r00, r01, r02, r10, r11, r12, r20, r21, r22,
        )  # fmt: skip
        go = (buf[_ROW_ACTIVE * W + v] != 0.0) & ok
        done = go & (theta <= _STEP_TOLERANCE)
        buf[(_ROW_R + 0) * W + v] = n00 if go else r00
        buf[(_ROW_R + 1) * W + v] = n01 if go else r01
        buf[(_ROW_R + 2) * W + v] = n02 if go else r02
        buf[(_ROW_R + 3) * W + v] = n10 if go else r10
        buf[(_ROW_R + 4) * W + v] = n11 if go else r11
        buf[(_ROW_R + 5) * W + v] = n12 if go else r12
        buf[(_ROW_R + 6) * W + v] = n20 if go else r20
        buf[(_ROW_R + 7) * W + v] = n21 if go else r21
        buf[(_ROW_R + 8) * W + v] = n22 if go else r22
        buf[_ROW_SETTLED * W + v] = 1.0 if done else buf[_ROW_SETTLED * W + v]
        buf[_ROW_ACTIVE * W + v] = 1.0 if (go & ~done) else 0.0


@nb.njit(cache=True)
def _fit_rotations(A, hint, R, failed):  # pragma: no cover - compiled
    """Rotations maximising ``tr(R_vᵀ A_v)``, each by Newton from ``hint[v]``.

    ``A``, ``hint``, ``R`` have shape (n, 3, 3); ``failed`` (n,) is set where
    Newton did not settle at a maximum (``R`` is then the last iterate).
    Each vertex ends exactly as :func:`_newton_rotation` from its hint would:
    blocks of vertices step together (:func:`_newton_lanes`) while more than
    a quarter of a block still moves; the few left finish one by one.
    Returns whether any failed.
    """
    n = A.shape[0]
    W = _LANES
    buf = np.empty(_ROWS * W)
    Av = np.empty((3, 3))
    Rv = np.empty((3, 3))
    any_failed = False
    for start in range(0, n, W):
        m = min(W, n - start)
        for v in range(W):
            if v < m:
                for b in range(3):
                    for a in range(3):
                        buf[(_ROW_A + 3 * b + a) * W + v] = A[start + v, b, a]
                        buf[(_ROW_R + 3 * b + a) * W + v] = hint[start + v, b, a]
                buf[_ROW_ACTIVE * W + v] = 1.0
            else:
                # padding lanes: inactive, with finite values
                for k in range(9):
                    buf[(_ROW_A + k) * W + v] = 1.0 if k % 4 == 0 else 0.0
                    buf[(_ROW_R + k) * W + v] = 1.0 if k % 4 == 0 else 0.0
                buf[_ROW_ACTIVE * W + v] = 0.0
            buf[_ROW_SETTLED * W + v] = 0.0
        steps = 0
        active = m
        while steps < _MAX_STEPS and 4 * active > W:
            _newton_lanes(buf)
            steps += 1
            active = 0
            for v in range(W):
                if buf[_ROW_ACTIVE * W + v] != 0.0:
                    active += 1
        for v in range(m):
            settled = buf[_ROW_SETTLED * W + v] != 0.0
            if buf[_ROW_ACTIVE * W + v] != 0.0 and steps < _MAX_STEPS:
                for b in range(3):
                    for a in range(3):
                        Av[b, a] = buf[(_ROW_A + 3 * b + a) * W + v]
                        Rv[b, a] = buf[(_ROW_R + 3 * b + a) * W + v]
                settled = _newton_rotation(Av, Rv, _MAX_STEPS - steps)
                for b in range(3):
                    for a in range(3):
                        buf[(_ROW_R + 3 * b + a) * W + v] = Rv[b, a]
            for b in range(3):
                for a in range(3):
                    R[start + v, b, a] = buf[(_ROW_R + 3 * b + a) * W + v]
            if not settled:
                failed[start + v] = True
                any_failed = True
    return any_failed


@nb.njit(cache=True)
def shape_local(
    X, E, Lp, Li, Lx, delta, rest_edges, mu, w, hint, LX, A, R, d, G
):  # pragma: no cover - compiled
    """The rotation-aware Laplacian term in one call: rotations, energy, half-gradient.

    A pass over the vertices computes ``l(p′)_v`` and the covariances, a
    second the rotations (Newton on SO(3) from the hints, a block of
    vertices at a time: :func:`_fit_rotations`); if every rotation settled,
    :func:`shape_residuals` follows in the same call.

    Parameters
    ----------
    X : ndarray, shape (n, 3)
    E : ndarray of int64, shape (e, 2)
        Edges; ``d_e = X[E[e, 0]] − X[E[e, 1]]``.
    Lp, Li, Lx : ndarray
        CSR arrays of the Laplacian ``L`` (n × n).
    delta : ndarray, shape (n, 3)
        Rest Laplacian coordinates ``L V0``.
    rest_edges : ndarray, shape (e, 3)
    mu : float
        Weight of the one-ring edges.
    w : float
        Weight of the term.
    hint : ndarray, shape (n, 3, 3) or (0, 3, 3)
        Starting rotations (empty: each vertex starts from the previous
        vertex's rotation, usually a neighbour's).
    LX : ndarray, shape (n, 3)
        Output: ``L X``.
    A : ndarray, shape (n, 3, 3)
        Output: covariances ``A_v = l(p′)_v δ_vᵀ + μ Σ_e d_e e0_eᵀ``.
    R : ndarray, shape (n, 3, 3)
        Output: rotations maximising ``tr(R_vᵀ A_v)`` where Newton settled.
    d : ndarray, shape (e, 3)
        Output: the edge vectors ``d_e`` (the stretch term's too).
    G : ndarray, shape (n, 3)
        Half-gradient, added to when every rotation settled.

    Returns
    -------
    energy : float
        The term's energy; 0 when some rotation did not settle.
    failed : ndarray of bool, shape (n,)
        Vertices where Newton did not settle at a maximum. If there are
        any, their rotations, then :func:`shape_residuals`, are left to the
        caller (libigl's SVD fit).
    """
    n = X.shape[0]
    failed = np.zeros(n, dtype=np.bool_)
    _covariances(X, E, Lp, Li, Lx, delta, rest_edges, mu, LX, A, d)
    if hint.shape[0] == n:
        any_failed = _fit_rotations(A, hint, R, failed)
    else:
        any_failed = _chain_rotations(A, R, failed)
    if any_failed:
        return 0.0, failed
    return shape_residuals(d, E, Lp, Li, Lx, LX, delta, rest_edges, mu, w, R, G), failed


@nb.njit(cache=True)
def _covariances(X, E, Lp, Li, Lx, delta, rest_edges, mu, LX, A, d):  # pragma: no cover
    """``L X`` into ``LX`` (n, 3), the covariances into ``A`` (n, 3, 3), ``d_e`` into ``d`` (e, 3).

    ``A_v`` starts as ``l(p′)_v δ_vᵀ``; a pass over the edges then adds
    ``μ d_e e0_eᵀ`` to both ends, so each ``A_v`` sums its edges in the
    order of their indices. See :func:`shape_local`.
    """
    for v in range(X.shape[0]):
        s0, s1, s2 = _row_times(Lp, Li, Lx, X, v)
        LX[v, 0] = s0
        LX[v, 1] = s1
        LX[v, 2] = s2
        x0 = delta[v, 0]
        x1 = delta[v, 1]
        x2 = delta[v, 2]
        Av = A[v]
        Av[0, 0], Av[0, 1], Av[0, 2] = s0 * x0, s0 * x1, s0 * x2
        Av[1, 0], Av[1, 1], Av[1, 2] = s1 * x0, s1 * x1, s1 * x2
        Av[2, 0], Av[2, 1], Av[2, 2] = s2 * x0, s2 * x1, s2 * x2
    for e in range(E.shape[0]):
        i = E[e, 0]
        j = E[e, 1]
        e0 = rest_edges[e, 0]
        e1 = rest_edges[e, 1]
        e2 = rest_edges[e, 2]
        for b in range(3):
            dc = X[i, b] - X[j, b]
            d[e, b] = dc
            db = mu * dc
            p0 = db * e0
            p1 = db * e1
            p2 = db * e2
            A[i, b, 0] += p0
            A[i, b, 1] += p1
            A[i, b, 2] += p2
            A[j, b, 0] += p0
            A[j, b, 1] += p1
            A[j, b, 2] += p2


@nb.njit(cache=True)
def _chain_rotations(A, R, failed):  # pragma: no cover - compiled
    """:func:`_fit_rotations` without hints: each vertex starts from the previous one's rotation.

    The first starts from the identity, and so does the one after a vertex
    that failed. Returns whether any failed.
    """
    Rv = np.zeros((3, 3))
    for b in range(3):
        Rv[b, b] = 1.0
    any_failed = False
    for v in range(A.shape[0]):
        if _newton_rotation(A[v], Rv, _MAX_STEPS):
            for b in range(3):
                for a in range(3):
                    R[v, b, a] = Rv[b, a]
        else:
            failed[v] = True
            any_failed = True
            for b in range(3):
                for a in range(3):
                    Rv[b, a] = 1.0 if a == b else 0.0
    return any_failed


@nb.njit(cache=True)
def shape_residuals(d, E, Lp, Li, Lx, LX, delta, rest_edges, mu, w, R, G):  # pragma: no cover
    """Second half of the rotation-aware Laplacian term: energy and half-gradient.

    With the rotations ``R`` (n, 3, 3) fitted, returns the energy
    ``w (Σ ‖l(p′)_v − R_v δ_v‖² + μ Σ_e (‖d_e − R_i e0‖² + ‖d_e − R_j e0‖²))``
    and adds ``w (Lᵀ r + μ Dᵀ (r0 + r1))`` to ``G`` (n, 3). ``d`` (e, 3) are
    the edge vectors; the other arguments as in :func:`shape_local`.
    """
    n = LX.shape[0]
    energy_lap = 0.0
    for v in range(n):
        x0 = delta[v, 0]
        x1 = delta[v, 1]
        x2 = delta[v, 2]
        r0 = LX[v, 0] - (R[v, 0, 0] * x0 + R[v, 0, 1] * x1 + R[v, 0, 2] * x2)
        r1 = LX[v, 1] - (R[v, 1, 0] * x0 + R[v, 1, 1] * x1 + R[v, 1, 2] * x2)
        r2 = LX[v, 2] - (R[v, 2, 0] * x0 + R[v, 2, 1] * x1 + R[v, 2, 2] * x2)
        energy_lap += r0 * r0 + r1 * r1 + r2 * r2
        for k in range(Lp[v], Lp[v + 1]):
            j = Li[k]
            a = w * Lx[k]
            G[j, 0] += a * r0
            G[j, 1] += a * r1
            G[j, 2] += a * r2
    energy_edges = 0.0
    wm = w * mu
    for e in range(E.shape[0]):
        i = E[e, 0]
        j = E[e, 1]
        x0 = rest_edges[e, 0]
        x1 = rest_edges[e, 1]
        x2 = rest_edges[e, 2]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for c in range(3):
            dc = d[e, c]
            ri = dc - (R[i, c, 0] * x0 + R[i, c, 1] * x1 + R[i, c, 2] * x2)
            rj = dc - (R[j, c, 0] * x0 + R[j, c, 1] * x1 + R[j, c, 2] * x2)
            energy_edges += ri * ri + rj * rj
            if c == 0:
                s0 = ri + rj
            elif c == 1:
                s1 = ri + rj
            else:
                s2 = ri + rj
        _add_opposite(G, i, j, wm * s0, wm * s1, wm * s2)
    return w * (energy_lap + mu * energy_edges)


@nb.njit(cache=True)
def stretch_local(d, E, k, rest_length, rest, R, G):  # pragma: no cover - compiled
    """Edge-length term ``Σ k (|d| − L0)²``: return the energy, add the half-gradient.

    ``d`` (e, 3) are the edge vectors ``d_e = X[E[e, 0]] − X[E[e, 1]]``
    (:func:`edge_vectors`). A collapsed edge (``|d| ≤ 1e-12 L0``)
    is pulled to its rest vector, rotated by its first endpoint's rotation
    when ``R`` (n, 3, 3) is given (an empty ``R`` leaves it unrotated).
    """
    rotated = R.shape[0] > 0
    energy = 0.0
    for e in range(E.shape[0]):
        i = E[e, 0]
        j = E[e, 1]
        d0 = d[e, 0]
        d1 = d[e, 1]
        d2 = d[e, 2]
        length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if length > 1e-12 * max(rest_length[e], 1e-300):
            gap = length - rest_length[e]
            energy += k[e] * gap * gap
            f = k[e] * gap / length
            r0 = f * d0
            r1 = f * d1
            r2 = f * d2
        else:
            t0 = rest[e, 0]
            t1 = rest[e, 1]
            t2 = rest[e, 2]
            if rotated:
                t0 = R[i, 0, 0] * rest[e, 0] + R[i, 0, 1] * rest[e, 1] + R[i, 0, 2] * rest[e, 2]
                t1 = R[i, 1, 0] * rest[e, 0] + R[i, 1, 1] * rest[e, 1] + R[i, 1, 2] * rest[e, 2]
                t2 = R[i, 2, 0] * rest[e, 0] + R[i, 2, 1] * rest[e, 1] + R[i, 2, 2] * rest[e, 2]
            r0 = d0 - t0
            r1 = d1 - t1
            r2 = d2 - t2
            energy += k[e] * (r0 * r0 + r1 * r1 + r2 * r2)
            r0 *= k[e]
            r1 *= k[e]
            r2 *= k[e]
        _add_opposite(G, i, j, r0, r1, r2)
    return energy


@nb.njit(cache=True, inline="always")
def _wedge_target(d0, d1, d2, n0, n1, n2, o0, o1, o2, tolerance):  # pragma: no cover
    """Closest point of ``d`` in the half-plane continuing the host, widened to a wedge.

    The half-plane is ``{x : x·n = 0, x·o ≥ 0}`` (unit normal ``n``, outward
    direction ``o``); a ``tolerance`` > 0 (radians) widens it to the wedge
    of that half-angle about it. Returns the three coordinates.
    """
    z = d0 * n0 + d1 * n1 + d2 * n2
    p0 = d0 - z * n0
    p1 = d1 - z * n1
    p2 = d2 - z * n2
    po = p0 * o0 + p1 * o1 + p2 * o2
    if po < 0.0:
        p0 -= po * o0
        p1 -= po * o1
        p2 -= po * o2
    if tolerance == 0.0:
        return p0, p1, p2
    ca = math.cos(tolerance)
    sa = math.sin(tolerance)
    plen = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if abs(z) <= math.tan(tolerance) * plen:
        return p0 + z * n0, p1 + z * n1, p2 + z * n2
    sc = max(plen * ca + abs(z) * sa, 0.0)
    inv = 1.0 / plen if plen > 0.0 else 1.0
    sz = sa if z > 0.0 else (-sa if z < 0.0 else 0.0)
    return (
        sc * (ca * p0 * inv + sz * n0),
        sc * (ca * p1 * inv + sz * n1),
        sc * (ca * p2 * inv + sz * n2),
    )


@nb.njit(cache=True)
def smooth_local(
    X, pairs, normal, outward, weights, tolerance, fixed_target, G
):  # pragma: no cover - compiled
    """Smooth-join term over cross-seam edges: return the energy, add the half-gradient.

    For each pair ``(s, f)`` the edge ``d = X[f] − X[s]`` is pulled to its
    target: ``fixed_target[p]`` when that array is non-empty (the paper's
    form), else the closest point of ``d`` in the half-plane continuing the
    host (normal ``normal[p]``, outward direction ``outward[p]``), widened
    to a wedge of half-angle ``tolerance`` radians when it is positive.
    """
    fixed = fixed_target.shape[0] > 0
    energy = 0.0
    for p in range(pairs.shape[0]):
        s = pairs[p, 0]
        f = pairs[p, 1]
        d0 = X[f, 0] - X[s, 0]
        d1 = X[f, 1] - X[s, 1]
        d2 = X[f, 2] - X[s, 2]
        if fixed:
            t0 = fixed_target[p, 0]
            t1 = fixed_target[p, 1]
            t2 = fixed_target[p, 2]
        else:
            t0, t1, t2 = _wedge_target(
                d0, d1, d2, normal[p, 0], normal[p, 1], normal[p, 2],
                outward[p, 0], outward[p, 1], outward[p, 2], tolerance,
            )  # fmt: skip
        r0 = d0 - t0
        r1 = d1 - t1
        r2 = d2 - t2
        wp = weights[p]
        energy += wp * (r0 * r0 + r1 * r1 + r2 * r2)
        _add_opposite(G, f, s, wp * r0, wp * r1, wp * r2)
    return energy


@nb.njit(cache=True)
def band_local(X, Kp, Ki, Kx, normal, outward, weights, tolerance, G):  # pragma: no cover
    """Band smooth-join term: return the energy, add the half-gradient ``Kᵀ W r``.

    Row ``p`` of the sparse fit ``K`` (CSR arrays ``Kp``, ``Ki``, ``Kx``; ``Ki`` int32 or
    int64, as scipy keeps it) gives
    the guest's direction off seam vertex ``p``, ``d = (K X)_p``; its target
    is the closest point in the half-plane (normal ``normal[p]``, outward
    ``outward[p]``) widened to a wedge of half-angle ``tolerance[p]``; its
    residual ``r = d − target`` weighs ``weights[p]``.
    """
    energy = 0.0
    for p in range(Kp.shape[0] - 1):
        d0, d1, d2 = _row_times(Kp, Ki, Kx, X, p)
        t0, t1, t2 = _wedge_target(
            d0, d1, d2, normal[p, 0], normal[p, 1], normal[p, 2],
            outward[p, 0], outward[p, 1], outward[p, 2], tolerance[p],
        )  # fmt: skip
        wp = weights[p]
        r0 = d0 - t0
        r1 = d1 - t1
        r2 = d2 - t2
        energy += wp * (r0 * r0 + r1 * r1 + r2 * r2)
        r0 *= wp
        r1 *= wp
        r2 *= wp
        for k in range(Kp[p], Kp[p + 1]):
            j = Ki[k]
            a = Kx[k]
            G[j, 0] += a * r0
            G[j, 1] += a * r1
            G[j, 2] += a * r2
    return energy


@nb.njit(cache=True, inline="always")
def _dot4(a, b, N):  # pragma: no cover - compiled
    """``Σ a[i] b[i]`` over the first ``N`` entries of two 1-D arrays.

    Four partial sums, so that the loop is not bound by the latency of one
    chain of additions; the result differs from a sequential sum by rounding.
    """
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    stop = N - N % 4
    for i in range(0, stop, 4):
        s0 += a[i] * b[i]
        s1 += a[i + 1] * b[i + 1]
        s2 += a[i + 2] * b[i + 2]
        s3 += a[i + 3] * b[i + 3]
    for i in range(stop, N):
        s0 += a[i] * b[i]
    return (s0 + s1) + (s2 + s3)


@nb.njit(cache=True)
def dot(a, b):  # pragma: no cover - compiled
    """``Σ a b`` of two C-contiguous arrays of one shape.

    Single-threaded on purpose: a BLAS ``ddot`` of more than about 10⁴
    entries wakes a pool of threads, which on a machine whose cores are
    busy costs milliseconds per call instead of microseconds.
    """
    x = a.ravel()
    y = b.ravel()
    return _dot4(x, y, x.shape[0])


@nb.njit(cache=True)
def lbfgs_pair(S, Y, slot, x_new, x, g_new, g):  # pragma: no cover - compiled
    """Write ``s = x_new − x`` and ``y = g_new − g`` into row ``slot`` of ``S``, ``Y``.

    ``S``, ``Y`` have shape (m, N); the four iterates are C-contiguous arrays
    of N entries. Returns ``(sᵀy, yᵀy)``.
    """
    a = x_new.ravel()
    b = x.ravel()
    c = g_new.ravel()
    e = g.ravel()
    sy = 0.0
    yy = 0.0
    for i in range(a.shape[0]):
        si = a[i] - b[i]
        yi = c[i] - e[i]
        S[slot, i] = si
        Y[slot, i] = yi
        sy += si * yi
        yy += yi * yi
    return sy, yy


@nb.njit(cache=True)
def lbfgs_first_loop(q, S, Y, rho, order, alpha):  # pragma: no cover - compiled
    """First half of the L-BFGS two-loop recursion, newest pair first.

    ``q`` (N,) is updated in place to ``q − Σ α_k y_k``; ``S``, ``Y`` (m, N)
    hold the pairs in the slots ``order`` (oldest first), ``rho`` (m,) their
    ``1 / sᵀy``; ``alpha`` (m,) receives the coefficients by slot. Each
    update of ``q`` and the next pair's product with it share one pass.
    """
    N = q.shape[0]
    k = order.shape[0] - 1
    if k < 0:
        return
    slot = order[k]
    a = rho[slot] * _dot4(S[slot], q, N)
    while k >= 0:
        alpha[slot] = a
        Yk = Y[slot]
        if k == 0:
            for i in range(N):
                q[i] -= a * Yk[i]
            break
        nxt = order[k - 1]
        Sn = S[nxt]
        s0 = 0.0
        s1 = 0.0
        stop = N - N % 2
        for i in range(0, stop, 2):
            q0 = q[i] - a * Yk[i]
            q1 = q[i + 1] - a * Yk[i + 1]
            q[i] = q0
            q[i + 1] = q1
            s0 += Sn[i] * q0
            s1 += Sn[i + 1] * q1
        for i in range(stop, N):
            q[i] -= a * Yk[i]
            s0 += Sn[i] * q[i]
        k -= 1
        slot = nxt
        a = rho[slot] * (s0 + s1)


@nb.njit(cache=True)
def lbfgs_second_loop(z, S, Y, rho, order, alpha):  # pragma: no cover - compiled
    """Second half of the two-loop recursion, oldest pair first (``z`` (N,) in place).

    Each update of ``z`` and the next pair's product with it share one pass.
    """
    N = z.shape[0]
    m = order.shape[0]
    if m == 0:
        return
    slot = order[0]
    b = _dot4(Y[slot], z, N)
    for k in range(m):
        c = alpha[slot] - rho[slot] * b
        Sk = S[slot]
        if k == m - 1:
            for i in range(N):
                z[i] += c * Sk[i]
            break
        nxt = order[k + 1]
        Yn = Y[nxt]
        s0 = 0.0
        s1 = 0.0
        stop = N - N % 2
        for i in range(0, stop, 2):
            z0 = z[i] + c * Sk[i]
            z1 = z[i + 1] + c * Sk[i + 1]
            z[i] = z0
            z[i + 1] = z1
            s0 += Yn[i] * z0
            s1 += Yn[i + 1] * z1
        for i in range(stop, N):
            z[i] += c * Sk[i]
            s0 += Yn[i] * z[i]
        slot = nxt
        b = s0 + s1


@nb.njit(cache=True)
def join_rows(n, free, x, fixed, bc):  # pragma: no cover - compiled
    """An (n, 3) array with rows ``free`` from ``x`` and rows ``fixed`` from ``bc``.

    ``X[free] = x; X[fixed] = bc`` in one call, for ``x`` (len(free), 3) and
    ``bc`` (len(fixed), 3); rows in neither are left unset.
    """
    X = np.empty((n, 3))
    _place_rows(X, free, x)
    _place_rows(X, fixed, bc)
    return X


@nb.njit(cache=True, inline="always")
def _place_rows(X, rows, values):  # pragma: no cover - compiled
    """``X[rows] = values`` for ``X`` (n, 3) and ``values`` (len(rows), 3)."""
    for k in range(rows.shape[0]):
        r = rows[k]
        X[r, 0] = values[k, 0]
        X[r, 1] = values[k, 1]
        X[r, 2] = values[k, 2]


@nb.njit(cache=True)
def step(x, t, d):  # pragma: no cover - compiled
    """``x + t * d`` for two arrays of one shape (m, k), in a new C-ordered array.

    Each entry is the product rounded, then the sum (as numpy's two
    operations round them: no fused multiply-add). Indexed entry by entry,
    so any memory order reads right (a flattened view of a non-C array would
    be a copy, and the sums written into it lost).
    """
    out = np.empty(x.shape)
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            out[i, j] = x[i, j] + t * d[i, j]
    return out


@nb.njit(cache=True)
def abs_max(d):  # pragma: no cover - compiled
    """``max |d|`` over a C-contiguous array (NaN if any entry is NaN, as numpy's)."""
    b = d.ravel()
    m = 0.0
    for i in range(b.shape[0]):
        v = abs(b[i])
        if v > m:
            m = v
        elif v != v:
            return v
    return m


@nb.njit(cache=True)
def take_rows(G, rows):  # pragma: no cover - compiled
    """``G[rows]``, shape (len(rows), 3), for ``G`` (n, 3)."""
    out = np.empty((rows.shape[0], 3))
    for k in range(rows.shape[0]):
        r = rows[k]
        out[k, 0] = G[r, 0]
        out[k, 1] = G[r, 1]
        out[k, 2] = G[r, 2]
    return out


@nb.njit(cache=True)
def abs_row_sums(ptr, val):  # pragma: no cover - compiled
    """Every row's ``Σ_k |A_ik|`` of a CSR matrix (its ``indptr``, ``data``), shape (n,).

    The stored entries in their order (duplicates apart), without the ``(nnz,)``
    temporaries of ``np.bincount`` over ``np.abs(data)``, whose sums it equals
    (for a matrix of a 1M-vertex guest, made at its set-up).
    """
    n = ptr.shape[0] - 1
    out = np.zeros(n)
    for i in range(n):
        s = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            s += abs(val[k])
        out[i] = s
    return out


@nb.njit(cache=True)
def gram_row_bound(ptr, idx, val, weights, n):  # pragma: no cover - compiled
    """``max_j Σ_i |w_i| |K_ij| Σ_k |K_ik|``: a bound of ``Kᵀ diag(w) K``'s rows' absolute sums.

    ``K`` in CSR (``indptr``, ``indices``, ``data``, ``n`` columns), ``weights``
    one per row. Row ``j`` of ``Kᵀ W K`` sums ``|Σ_i K_ij w_i K_il|`` over ``l``,
    at most ``Σ_i |w_i| |K_ij| Σ_l |K_il|``; so the largest is a bound of its
    largest eigenvalue (Gershgorin) without forming the product.
    """
    rows = abs_row_sums(ptr, val)
    col = np.zeros(n)
    for i in range(ptr.shape[0] - 1):
        a = abs(weights[i]) * rows[i]
        for k in range(ptr[i], ptr[i + 1]):
            col[idx[k]] += a * abs(val[k])
    m = 0.0
    for j in range(n):
        if col[j] > m:
            m = col[j]
    return m
