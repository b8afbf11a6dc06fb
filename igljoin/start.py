"""Where the local/global iteration (§4.5) starts: the rest guest moved onto its seam.

:func:`rigid_start` places the rest guest by the rigid motion that best fits
its seam onto the targets; the solver then extends the remaining seam move
smoothly (:meth:`igljoin.solve.LocalGlobalSolver.extend`), and :func:`bulge`
lifts a guest that this leaves compressed (what it reads of the rest guest and
the host, :func:`bulge_basis`, is made once per set-up). A re-solve starts
from an earlier result instead, moved the same way; along a path of
re-solves (a slider) :func:`path_prediction` first carries it on by the
earlier results' own moves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba as nb
import numpy as np

from .boundary import SelectedCurve, boundary_loops
from .correspond import rigid_fit
from .frames import face_areas, seam_frames
from .mesh import Mesh

__all__ = ["rigid_start", "path_prediction", "bulge", "bulge_basis", "BulgeBasis"]


def rigid_start(V: np.ndarray, seam: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``V`` moved by the rigid motion that best fits ``V[seam]`` onto ``targets``.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    seam : ndarray of int64, shape (s,)
    targets : ndarray, shape (s, 3)

    Returns
    -------
    ndarray, shape (n, 3)
    """
    R, t = rigid_fit(V[seam], targets)
    return V @ R.T + t


def path_prediction(
    X: np.ndarray, earlier: list[np.ndarray], seam: np.ndarray, targets: np.ndarray
) -> np.ndarray:
    """``X`` carried on along a path of minima towards new seam ``targets``.

    ``X`` and every array of ``earlier`` are minima of the same energy for
    their own seam positions (results of one solver, each solved from the
    one before). The seam move ``targets − X[seam]`` is fitted, in the least
    squares, by the moves between them, ``Σ c_j (X[seam] − X_j[seam])``, and
    the same combination of the whole guests' moves is added:
    ``X + Σ c_j (X − X_j)``. The minimum depends smoothly on the seam, so
    the part of the move the earlier ones span is predicted to first order
    (the solver uses one earlier minimum: :data:`igljoin.join.PATH_LENGTH`),
    whereas extending a seam move smoothly predicts none of the guest's own
    response; the part they do not span is left to that extension.

    Parameters
    ----------
    X : ndarray, shape (n, 3)
        The latest minimum.
    earlier : list of ndarray, each shape (n, 3)
        Earlier minima (any order; none: ``X`` is returned).
    seam : ndarray of int64, shape (s,)
    targets : ndarray, shape (s, 3)

    Returns
    -------
    ndarray, shape (n, 3)
        The prediction; its seam is near, not on, ``targets``.
    """
    if not earlier:
        return X
    D = np.stack([(X[seam] - Xj[seam]).ravel() for Xj in earlier], axis=1)
    c = np.linalg.lstsq(D, (targets - X[seam]).ravel(), rcond=None)[0]
    out = X.copy()
    for cj, Xj in zip(c, earlier):
        out += cj * (X - Xj)
    return out


@dataclass(frozen=True)
class BulgeBasis:
    """What a bulge reads of the rest guest and the host: made once per set-up.

    Attributes
    ----------
    rest_area : float
        The rest guest's area.
    normal : ndarray, shape (3,)
        Unit mean of the host's seam normals: the direction of the lift.
    side : float
        Its sign: the side the host surface curves towards.
    height : float
        The largest lift tried: the rest guest's bounding-box diagonal.
    """

    rest_area: float
    normal: np.ndarray
    side: float
    height: float


def bulge_basis(
    V: np.ndarray, F: np.ndarray, seam: np.ndarray, host: Mesh, curve: SelectedCurve | None
) -> BulgeBasis | None:
    """The parts of :func:`bulge` that depend on the rest guest and the host only.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
        The rest guest.
    seam : ndarray of int64, shape (s,)
        Its seam vertices.
    host : Mesh
    curve : SelectedCurve or None
        The host curve of a single seam.

    Returns
    -------
    BulgeBasis or None
        ``None`` where no guest is ever lifted: several seams, an open
        curve, a guest that is not a disk, or host seam normals that cancel.
    """
    if curve is None or not curve.closed or len(boundary_loops(F)) != 1:
        return None
    rest = face_areas(V, F).sum()
    frames = seam_frames(host.V, host.F, curve.indices, True)
    N = frames.normal.mean(axis=0)
    if np.linalg.norm(N) == 0:
        return None
    N = N / np.linalg.norm(N)
    side = float(np.mean(-frames.inward @ N))
    if abs(side) < 1e-3:
        side = float((V.mean(axis=0) - V[seam].mean(axis=0)) @ N) or 1.0
    return BulgeBasis(rest, N, side, float(np.linalg.norm(np.ptp(V, axis=0))))


def bulge(
    X: np.ndarray,
    F: np.ndarray,
    basis: BulgeBasis | None,
    bump: Callable[[], np.ndarray],
) -> np.ndarray:
    """Lift a compressed disk-like guest off its plane so that it bulges instead of shrinking.

    A guest whose boundary is longer than the host's (paper §5: "it bulged
    to match the shape of the host") would otherwise start from a flat,
    compressed state that the iteration leaves only slowly. The lift is
    the guest's response to a unit load along the host's mean seam normal,
    on the side the host surface curves towards, with its height chosen
    so that the guest's area is its rest area.

    Parameters
    ----------
    X : ndarray, shape (n, 3)
        Start positions of the guest.
    F : ndarray of int64, shape (m, 3)
        Its faces.
    basis : BulgeBasis or None
        From :func:`bulge_basis` (``None``: no lift).
    bump : callable
        Returns the guest's response to a unit load on its free vertices,
        shape (n,) (:meth:`igljoin.solve.LocalGlobalSolver.bump`); called
        only when a lift is made.

    Returns
    -------
    ndarray, shape (n, 3)
        ``X``, lifted where the guest is a disk on a closed curve and is
        compressed by more than 0.1 % of its area.
    """
    if basis is None:
        return X
    rest = basis.rest_area
    if face_areas(X, F).sum() >= (1.0 - 1e-3) * rest:
        return X
    phi = bump()
    if phi.max() <= 0:
        return X
    lift = np.sign(basis.side) * (phi / phi.max())[:, None] * basis.normal

    Xc, Lc = np.ascontiguousarray(X, dtype=np.float64), np.ascontiguousarray(lift)
    Fc = np.ascontiguousarray(F, dtype=np.int64)
    out = np.empty(len(Fc))

    def area(a):
        return _lifted_areas(Xc, Lc, float(a), Fc, out).sum()

    hi = basis.height
    if area(hi) < rest:
        return X + hi * lift
    lo = 0.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if area(mid) < rest else (lo, mid)
    return X + 0.5 * (lo + hi) * lift


@nb.njit(cache=True)
def _lifted_areas(
    X: np.ndarray, lift: np.ndarray, a: float, F: np.ndarray, out: np.ndarray
) -> np.ndarray:
    """``face_areas(X + a * lift, F)`` into ``out`` (m,), without the (n, 3) temporaries.

    Compiled; each corner is ``X + (a * lift)`` and each area is rounded as
    :func:`igljoin.frames.face_areas` rounds it (the cross product's two
    products and difference, the squares summed left to right, the root,
    the half), so the floats are its floats; the caller sums them with
    numpy, as before.
    """
    for f in range(len(F)):
        i, j, k = F[f, 0], F[f, 1], F[f, 2]
        p0 = X[i, 0] + a * lift[i, 0]
        p1 = X[i, 1] + a * lift[i, 1]
        p2 = X[i, 2] + a * lift[i, 2]
        a0 = (X[j, 0] + a * lift[j, 0]) - p0
        a1 = (X[j, 1] + a * lift[j, 1]) - p1
        a2 = (X[j, 2] + a * lift[j, 2]) - p2
        b0 = (X[k, 0] + a * lift[k, 0]) - p0
        b1 = (X[k, 1] + a * lift[k, 1]) - p1
        b2 = (X[k, 2] + a * lift[k, 2]) - p2
        c0 = a1 * b2 - a2 * b1
        c1 = a2 * b0 - a0 * b2
        c2 = a0 * b1 - a1 * b0
        out[f] = 0.5 * math.sqrt((c0 * c0 + c1 * c1) + c2 * c2)
    return out
