"""Exact per-vertex best-fit rotations, vectorised and warm-started.

The rotation-aware shape term needs, at every local step, the rotation
``R_v`` maximising ``tr(R_vᵀ A_v)`` for one 3 × 3 covariance ``A_v`` per
vertex (a weighted Procrustes fit). libigl's ``fit_rotations`` does one SVD
per vertex; here the fit is a Newton iteration on SO(3) run on all vertices
at once in structure-of-arrays layout, started from the previous local
step's rotations. Near convergence the rotations move little between
iterations and one or two Newton steps reach machine precision.

A vertex whose Newton iteration does not settle, or settles where the
second-order condition fails (a saddle, or a covariance too degenerate to
fix the rotation), is handed to ``igl.fit_rotations`` (double precision), so
the result is always the global maximiser libigl would return.

Layout: ``A`` and ``R`` have shape (3, 3, n); ``A[i, j]`` is the n-vector of
the (i, j) entries.
"""

from __future__ import annotations

import igl
import numpy as np

__all__ = ["fit_rotations", "fit_rotations_igl"]

#: Newton stops once every rotation increment is below this (radians); the
#: next increment would be below its square, i.e. at rounding level.
STEP_TOLERANCE = 1e-7

#: Newton steps before a vertex is handed to libigl.
MAX_STEPS = 8

#: Relative margin of the second-order (maximum) condition; below it libigl decides.
DEGENERATE = 1e-9


def fit_rotations_igl(A: np.ndarray) -> np.ndarray:
    """Best-fit rotations by libigl's ``fit_rotations`` (double precision).

    Parameters
    ----------
    A : ndarray, shape (3, 3, n)
        Covariances; ``R_v`` maximises ``tr(R_vᵀ A_v)``.

    Returns
    -------
    ndarray, shape (3, 3, n)
    """
    n = A.shape[2]
    if n == 0:
        return np.zeros((3, 3, 0))
    # libigl stacks S coordinate-major, S[a n + v, b] = A_v[b, a], and returns
    # R (3, 3n) with R[:, 3v:3v+3] the rotation of vertex v
    S = np.ascontiguousarray(A.transpose(1, 2, 0).reshape(3 * n, 3))
    R = np.asarray(igl.fit_rotations(S, False))
    return np.ascontiguousarray(R.reshape(3, n, 3).transpose(0, 2, 1))


def _matmul(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Per-vertex products ``P_v Q_v`` of (3, 3, n) stacks."""
    return np.einsum("ikn,kjn->ijn", P, Q, optimize=False)


def _tmatmul(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Per-vertex products ``P_vᵀ Q_v`` of (3, 3, n) stacks."""
    return np.einsum("kin,kjn->ijn", P, Q, optimize=False)


def _newton_step(R: np.ndarray, A: np.ndarray):
    """One Newton step of ``max tr(Rᵀ A)`` on SO(3) from ``R``.

    With ``M = Rᵀ A`` and ``R ← R exp([ω]×)``, the objective is
    ``tr M − sᵀω − ½ ωᵀ H ω + O(|ω|³)`` with ``s`` the axial vector of
    ``M − Mᵀ`` and ``H = tr(M) I − sym(M)``; the step is ``ω = −H⁻¹ s``.

    Returns the new rotations, ``|ω|`` and whether ``H`` was positive definite
    (relative margin :data:`DEGENERATE`), each per vertex.
    """
    M = _tmatmul(R, A)
    s0 = M[1, 2] - M[2, 1]
    s1 = M[2, 0] - M[0, 2]
    s2 = M[0, 1] - M[1, 0]
    tr = M[0, 0] + M[1, 1] + M[2, 2]
    a = tr - M[0, 0]
    d = tr - M[1, 1]
    f = tr - M[2, 2]
    b = -0.5 * (M[0, 1] + M[1, 0])
    c = -0.5 * (M[0, 2] + M[2, 0])
    e = -0.5 * (M[1, 2] + M[2, 1])
    # adjugate of the symmetric H = [[a, b, c], [b, d, e], [c, e, f]]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + c * c02
    scale = np.abs(a) + np.abs(d) + np.abs(f) + 1e-300
    pd = (a > DEGENERATE * scale) & (c22 > DEGENERATE * scale**2) & (det > DEGENERATE * scale**3)
    inv = -1.0 / np.where(pd, det, 1.0)
    w0 = (c00 * s0 + c01 * s1 + c02 * s2) * inv
    w1 = (c01 * s0 + c11 * s1 + c12 * s2) * inv
    w2 = (c02 * s0 + c12 * s1 + c22 * s2) * inv
    theta = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    # Cayley retraction exp([ω]×) ≈ (I − [v]×)⁻¹ (I + [v]×), v = ω / 2: exactly
    # orthogonal and equal to the exponential to second order, so the step
    # keeps Newton's quadratic convergence without trigonometry
    w0, w1, w2 = 0.5 * w0, 0.5 * w1, 0.5 * w2
    alpha = 2.0 / (1.0 + w0 * w0 + w1 * w1 + w2 * w2)
    E = np.empty_like(R)
    E[0, 0] = 1.0 - alpha * (w1 * w1 + w2 * w2)
    E[1, 1] = 1.0 - alpha * (w0 * w0 + w2 * w2)
    E[2, 2] = 1.0 - alpha * (w0 * w0 + w1 * w1)
    p01, p02, p12 = alpha * w0 * w1, alpha * w0 * w2, alpha * w1 * w2
    aw0, aw1, aw2 = alpha * w0, alpha * w1, alpha * w2
    E[0, 1] = p01 - aw2
    E[1, 0] = p01 + aw2
    E[0, 2] = p02 + aw1
    E[2, 0] = p02 - aw1
    E[1, 2] = p12 - aw0
    E[2, 1] = p12 + aw0
    return _matmul(R, E), theta, pd


def fit_rotations(A: np.ndarray, R0: np.ndarray | None = None) -> np.ndarray:
    """Rotations ``R_v`` maximising ``tr(R_vᵀ A_v)`` (the closest rotations to ``A_v``).

    Parameters
    ----------
    A : ndarray, shape (3, 3, n)
        Covariances ``A_v = Σ_k w_k y_k x_kᵀ`` of a fit ``R_v x_k ≈ y_k``.
    R0 : ndarray, shape (3, 3, n), optional
        Starting rotations (e.g. the previous local step's). Without them
        libigl's ``fit_rotations`` computes all rotations.

    Returns
    -------
    ndarray, shape (3, 3, n)
        Proper rotations, equal to libigl's double-precision
        ``fit_rotations`` to rounding wherever the maximiser is unique.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> R = Rotation.from_rotvec([[0.1, 0.2, 0.3], [1.0, -2.0, 0.5]]).as_matrix()
    >>> A = (R @ np.diag([3.0, 2.0, 1.0])).transpose(1, 2, 0)
    >>> R0 = np.eye(3)[:, :, None].repeat(2, axis=2)
    >>> bool(np.allclose(fit_rotations(A, R0), R.transpose(1, 2, 0)))
    True
    """
    A = np.asarray(A, dtype=np.float64)
    n = A.shape[2]
    if R0 is None or n == 0:
        return fit_rotations_igl(A)
    R = np.array(R0, dtype=np.float64, order="C")
    done_ok = np.zeros(n, dtype=bool)
    active = None  # None: every vertex; else the indices still iterating
    Ra, Aa = R, A
    for _ in range(MAX_STEPS):
        Ra, theta, pd = _newton_step(Ra, Aa)
        settled = theta <= STEP_TOLERANCE
        # a settled vertex is a maximum (H positive definite), hence the global one
        ok = settled & pd
        keep = ~settled & pd & np.isfinite(theta)
        if active is None:
            R = Ra
            done_ok = ok
        else:
            R[:, :, active] = Ra
            done_ok[active[ok]] = True
        n_keep = int(np.count_nonzero(keep))
        if n_keep == 0:
            break
        if active is None and n_keep > n // 4:
            # most vertices still move: another step on all of them is cheaper than
            # gathering (it only refines the settled ones further)
            continue
        # continue on the unsettled vertices only (np.take keeps the layout contiguous)
        idx = np.flatnonzero(keep)
        active = idx if active is None else active[idx]
        Ra, Aa = np.take(Ra, idx, axis=2), np.take(Aa, idx, axis=2)
    bad = np.flatnonzero(~done_ok)
    if bad.size:
        R[:, :, bad] = fit_rotations_igl(A[:, :, bad])
    return R
