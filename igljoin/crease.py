"""Crease along a seam, measured at the scale of a band rather than of triangles.

At each host curve vertex the host and the guest are each fitted over a band
of width ``band`` on their own side of the seam (:func:`igljoin.bandfit.band_fit`);
the crease is the angle between the direction in which the guest leaves the
seam and the direction in which the host surface, continued across it, would
leave it. A smooth surface cut anywhere and by any triangulation of the cut
(round, zig-zag along edges, split triangles with slivers) measures near zero.

Two figures use the same fit:

* :func:`seam_crease` — the joined guest against the host (the result's
  ``crease_deg``);
* :func:`input_crease` — the rest guest, moved rigidly onto the host curve,
  against the host: how creased the two surfaces meet before any shape change
  (for a piece cut from the host, the uncut surface's own crease).

Each comes with its *noise*: the standard error of the crease from the
residuals of the two fits (:attr:`igljoin.bandfit.BandFit.slope_error`), the
finest crease the band can tell from the scan noise of the surfaces there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bandfit import BAND_EDGES, BandFit, band_fit, median_edge_near
from .correspond import rigid_fit
from .frames import unit
from .seam_geometry import SeamGeometry

__all__ = [
    "CreaseMeasure",
    "seam_crease",
    "input_crease",
    "default_band",
    "report",
    "NOISE_SIGMAS",
]

#: Standard errors subtracted from a crease before it counts as one
#: (``beyond_noise_max``): two, about 95 % one-sided.
NOISE_SIGMAS = 2.0


@dataclass(frozen=True)
class CreaseMeasure:
    """Crease angles along one curve.

    Attributes
    ----------
    angles : ndarray, shape (k,)
        Degrees in ``[0, 180]`` at each host curve vertex; 0 is a smooth join.
    band : float
        Width of the band the surfaces were fitted over, in mesh units.
    noise : ndarray, shape (k,)
        Degrees: standard error of each angle from the fits' residuals.
    """

    angles: np.ndarray
    band: float
    noise: np.ndarray


def default_band(seam: SeamGeometry, guest_curve: np.ndarray | None = None) -> float:
    """:data:`~igljoin.bandfit.BAND_EDGES` median edge lengths of the coarser side near the seam.

    Parameters
    ----------
    seam : SeamGeometry
    guest_curve : ndarray of int64, shape (s,), optional
        Guest curve vertices whose edges count (default
        ``seam.guest_at_host``; a join passes all its seam vertices).

    Returns
    -------
    float
        In mesh units; also at most a quarter of the guest's size (twice its
        largest distance from its centroid).
    """
    guest_curve = seam.guest_at_host if guest_curve is None else guest_curve
    h = max(
        median_edge_near(seam.Vh, seam.Fh, seam.host_curve),
        median_edge_near(seam.Vg, seam.Fg, guest_curve),
    )
    used = np.zeros(len(seam.Vg), dtype=bool)
    used[np.asarray(seam.Fg, dtype=np.int64).reshape(-1)] = True  # the vertices of its faces
    Vu = seam.Vg[used] if used.any() else np.zeros((1, 3))
    # twice the largest distance from the centroid: unlike a bounding box's
    # diagonal, it does not change when the guest is turned
    size = 2.0 * float(np.linalg.norm(Vu - Vu.mean(axis=0), axis=1).max())
    return float(min(BAND_EDGES * h, 0.25 * size)) if size > 0 else float(BAND_EDGES * h)


def _measure(guest, host, R: np.ndarray | None = None, g=None) -> CreaseMeasure:
    """Angle between the guest's direction off the seam and the host's continued."""
    if g is None:
        g = guest.frames.inward if R is None else guest.frames.inward @ R.T
    cos = np.clip(np.einsum("ij,ij->i", g, -host.frames.inward), -1.0, 1.0)
    noise = np.hypot(guest.slope_error, host.slope_error)
    return CreaseMeasure(np.degrees(np.arccos(cos)), float(host.band), np.degrees(noise))


def _host_fit(seam: SeamGeometry, band: float) -> BandFit:
    return band_fit(seam.Vh, seam.Fh, seam.host_curve, seam.closed, band)


def seam_crease(
    seam: SeamGeometry,
    band: float | None = None,
    rest: np.ndarray | None = None,
    host_fit: BandFit | None = None,
    rest_fit: BandFit | None = None,
) -> CreaseMeasure:
    """Crease between a guest lying on the host curve and the host, at band scale.

    Parameters
    ----------
    seam : SeamGeometry
        The host, its curve and the guest on it (joined, or in place for an
        uncut reference).
    band : float, optional
        Band width in mesh units (default :func:`default_band`).
    rest : ndarray, shape (n_g, 3), optional
        Rest positions of a deformed guest. The guest is then fitted in its rest
        coordinates (which band vertices, at which ``u, v``), as the smooth-join
        term does; the noise is that of the rest surface. Without it the guest
        is fitted as it lies (for a guest in place, the two agree).
    host_fit : BandFit, optional
        The host's band fit along the host curve at ``band``, if already made.
    rest_fit : BandFit, optional
        With ``rest``: the rest guest's band fit along ``seam.guest_at_host``,
        if already made.

    Returns
    -------
    CreaseMeasure
    """
    if band is None:
        band = default_band(seam)
    host = host_fit or _host_fit(seam, band)
    if rest is not None:
        guest = rest_fit or band_fit(rest, seam.Fg, seam.guest_at_host, seam.closed, band)
        c = guest.weights @ seam.Vg
        T = host.frames.tangent
        return _measure(guest, host, g=unit(c - np.einsum("ij,ij->i", c, T)[:, None] * T))
    guest = band_fit(
        seam.Vg, seam.Fg, seam.guest_at_host, seam.closed, band, curve_points=seam.host_points
    )
    return _measure(guest, host)


def input_crease(
    seam: SeamGeometry,
    band: float,
    host_fit: BandFit | None = None,
    guest_fit: BandFit | None = None,
) -> CreaseMeasure:
    """Crease at which the rest guest, moved rigidly onto the host curve, meets the host.

    The guest's band fit is rotated by the rigid motion that best maps its
    seam (``seam.Vg[seam.guest_at_host]``) onto the host curve; nothing is
    solved.

    Parameters
    ----------
    seam : SeamGeometry
        As in :func:`seam_crease`, with the guest at rest.
    band : float
        Band width in mesh units.
    host_fit : BandFit, optional
        The host's band fit along the host curve at ``band``, if already made.
    guest_fit : BandFit, optional
        The rest guest's band fit along ``seam.guest_at_host`` at ``band``, if
        already made.

    Returns
    -------
    CreaseMeasure
    """
    R, _ = rigid_fit(seam.Vg[seam.guest_at_host], seam.host_points)
    host = host_fit or _host_fit(seam, band)
    guest = guest_fit or band_fit(seam.Vg, seam.Fg, seam.guest_at_host, seam.closed, band)
    return _measure(guest, host, R)


def report(measures: list[CreaseMeasure]) -> dict:
    """Summary of one or more crease measures (e.g. one per seam) for a report.

    Parameters
    ----------
    measures : list of CreaseMeasure

    Returns
    -------
    dict
        ``mean``, ``median``, ``p95``, ``min``, ``max`` of the angles (degrees);
        ``band`` (the widest, mesh units); ``noise`` (the median standard
        error, degrees); ``beyond_noise_max``: the largest angle less
        :data:`NOISE_SIGMAS` of its standard errors — the largest crease the
        fits can tell from their noise (what warnings read).
    """
    from .metrics import summary

    angles = np.concatenate([m.angles for m in measures]) if measures else np.zeros(0)
    noise = np.concatenate([m.noise for m in measures]) if measures else np.zeros(0)
    clear = angles - NOISE_SIGMAS * noise
    return {
        **summary(angles),
        "band": max((m.band for m in measures), default=None),
        "noise": float(np.median(noise)) if noise.size else None,
        "beyond_noise_max": float(clear.max()) if clear.size else None,
    }
