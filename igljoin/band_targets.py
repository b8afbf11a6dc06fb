"""Which crease the band smooth join removes: the one coherent along the seam.

The band fits (:mod:`igljoin.bandfit`) give, at each seam vertex, the signed
*elevation* ``φ`` of the rest guest's direction off the seam above the host's
tangent plane continued across it (about the curve tangent; the rest guest
moved rigidly onto the host curve). ``φ`` is the crease the inputs meet at,
plus the error of the fits: scan noise, the facets of a coarse mesh, a sliver.

A crease that joining should remove is coherent along the seam (a tube that
arrives at an angle, a patch whose boundary is too short): it is a smooth
function of the position along the seam, spanning several band widths. The
error of the fits is not: it changes from one vertex to the next. So ``φ`` is
fitted by a few smooth modes along the seam (Fourier modes of a closed seam,
Legendre polynomials of an open one), and the join removes each mode's
deviation from the angle asked for (0: the smooth join; ``join_angle``) only
as far as it stands clear of its standard error; the rest of ``φ`` is kept as
the rest guest has it: ``ψ = φ − removed``. A piece joined back where it was
cut from then keeps its shape exactly (its modes are insignificant), while a
guest that meets the host at an angle is turned smooth.

:func:`kept_elevation` computes ``ψ``; :func:`tilted_frames` tilts the host
frames by it, which is all the smooth-join term needs.
"""

from __future__ import annotations

import numpy as np

from .bandfit import along_curve_reach
from .correspond import rigid_fit
from .frames import SeamFrames, unit
from .polyline import arc_lengths, polyline_length, segment_lengths

__all__ = [
    "kept_elevation",
    "tilted_frames",
    "BANDS_PER_MODE",
    "MAX_MODE",
    "SIGNIFICANCE_LEVEL",
    "SMALLEST_REMOVED_DEG",
]

#: A mode along the seam has at least this many band widths per half-period, so
#: that it averages several independent band fits.
BANDS_PER_MODE = 2.0

#: Highest mode along the seam (a tube's bend is mode 1, an oval's mode 2).
MAX_MODE = 4

#: A mode of the crease is removed only beyond this one-sided quantile of Student's t
#: (times its standard error): 0.975, about two standard errors for many fits.
SIGNIFICANCE_LEVEL = 0.975

#: Nor below this many degrees, whatever its error: a thousandth of a radian is far
#: below what a join needs and what a band fit resolves on any mesh, and chasing it
#: only costs iterations (a tube joined to its exact continuation reads 3e-4°).
SMALLEST_REMOVED_DEG = 0.05


def _seam_modes(P: np.ndarray, closed: bool, band: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth functions along the seam (k, m) and each vertex's share of its length (k,).

    A closed seam gets the Fourier modes ``1, cos θ, sin θ, …`` of its arc-length
    angle, an open one Legendre polynomials of its arc-length parameter; as
    many as fit :data:`BANDS_PER_MODE` bands into each half-period, at most
    :data:`MAX_MODE`.
    """
    s, length = arc_lengths(P, closed)
    k = len(P)
    seg = segment_lengths(P, closed)
    if closed:
        share = 0.5 * (seg + np.roll(seg, 1))
    else:
        share = 0.5 * (np.r_[seg, 0.0] + np.r_[0.0, seg])
    if length <= 0 or k < 2:
        return np.ones((k, 1)), np.ones(k)
    order = int(np.clip(length / (2.0 * BANDS_PER_MODE * band), 0, MAX_MODE))
    if closed:
        theta = 2.0 * np.pi * s / length
        cols = [np.ones(k)]
        for j in range(1, order + 1):
            cols += [np.cos(j * theta), np.sin(j * theta)]
    else:
        x = 2.0 * s / length - 1.0
        cols = [np.polynomial.legendre.legval(x, np.eye(order + 1)[j]) for j in range(order + 1)]
    return np.stack(cols, axis=1), share / length


def kept_elevation(
    host: SeamFrames,
    guest_inward: np.ndarray,
    guest_points: np.ndarray,
    targets: np.ndarray,
    slope_error: np.ndarray,
    closed: bool,
    band: float,
    join_angle: float | None = None,
    join_side: str = "guest",
) -> tuple[np.ndarray, np.ndarray]:
    """Elevation (radians) the join keeps at each seam vertex, and the one it removes.

    Parameters
    ----------
    host : SeamFrames
        Host frames (band fit) at each guest seam vertex's target, shape (s, 3) each.
    guest_inward : ndarray, shape (s, 3)
        Rest guest's band-fitted direction into the guest at each seam vertex.
    guest_points : ndarray, shape (s, 3)
        Rest positions of the guest seam vertices.
    targets : ndarray, shape (s, 3)
        Their positions on the host curve.
    slope_error : ndarray, shape (s,)
        Standard error of each elevation (radians), host and guest fits combined.
    closed : bool
    band : float
        Band width (mesh units).
    join_angle : float, optional
        Degrees: the elevation the guest is to leave the host at (0 or None:
        the smooth join). What is removed is the significant part of the
        coherent crease's deviation from it.
    join_side : {"guest", "normal", "opposite"}
        Sign of ``join_angle``: the side the rest guest lies on (the sign of its
        mean elevation; the normal's side if that is zero), the host normal's
        side, or the other.

    Returns
    -------
    kept : ndarray, shape (s,)
        ``ψ = φ − removed``: the elevation the joined guest leaves the seam at.
    removed : ndarray, shape (s,)
        The coherent, significant part of the crease the join removes.
    """
    R, _ = rigid_fit(guest_points, targets)
    g = guest_inward @ R.T
    outward = -host.inward
    phi = np.arctan2(np.einsum("ij,ij->i", g, host.normal), np.einsum("ij,ij->i", g, outward))
    # a band fit spans ``reach`` along the seam (less than ``band`` round a tube's end)
    reach = min(band, along_curve_reach(targets, closed, host.normal, band))
    B, share = _seam_modes(targets, closed, reach)
    # weighted least squares of φ on the modes, each vertex weighing by its share
    # of the seam; neighbouring fits share one band, so count one independent
    # error per band of seam when taking the coefficients' standard errors
    W = share / share.sum()
    H = B.T @ (W[:, None] * B)
    Hinv = np.linalg.pinv(H)
    coef = Hinv @ (B.T @ (W * phi))
    length = polyline_length(targets, closed)
    correlated = max(1.0, reach * len(phi) / max(length, 1e-300))
    A = Hinv @ (B.T * W)  # coef = A @ phi
    # the error of each φ is that of its two band fits (from their residuals),
    # counted once per fit-width of seam: neighbouring fits share their vertices
    independent = max(len(phi) / correlated, 1.0)
    dof = max(independent - B.shape[1], 1.0)
    error2 = slope_error**2
    se = np.sqrt((A**2 @ error2) * correlated)
    from scipy.special import stdtrit  # Student's t quantile (scipy.stats costs 0.6 s to load)

    # two-sided 95 % of Student's t over the independent fits less the modes: wider
    # where a short seam holds few independent fits (about 2 standard errors for many)
    quantile = float(stdtrit(dof, SIGNIFICANCE_LEVEL))
    threshold = np.maximum(quantile * se, np.radians(SMALLEST_REMOVED_DEG))
    # the join removes the significant part of the crease's deviation from the angle
    # asked for (0: the smooth join); the rest stays as the rest guest has it
    target = np.zeros_like(coef)
    if join_angle:
        side = {"normal": 1.0, "opposite": -1.0}.get(join_side, np.sign(coef[0]) or 1.0)
        target[0] = side * np.radians(join_angle)  # mode 0 is the constant along the seam
    deviation = coef - target
    removed = B @ (np.sign(deviation) * np.maximum(np.abs(deviation) - threshold, 0.0))
    return phi - removed, removed


def tilted_frames(host: SeamFrames, kept: np.ndarray) -> SeamFrames:
    """Host frames turned about the tangent so that the continued plane rises by ``kept``.

    Parameters
    ----------
    host : SeamFrames
        Shape (s, 3) each.
    kept : ndarray, shape (s,)
        Radians.

    Returns
    -------
    SeamFrames
        ``inward`` is minus the tilted outward direction; ``normal`` is turned with it.
    """
    c, s = np.cos(kept)[:, None], np.sin(kept)[:, None]
    outward = -host.inward
    tilted_out = unit(c * outward + s * host.normal)
    tilted_normal = unit(c * host.normal - s * outward)
    return SeamFrames(normal=tilted_normal, tangent=host.tangent, inward=-tilted_out)
