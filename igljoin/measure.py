"""Measurements of a join: the report's metrics, computed from plain arrays.

Functions, not methods: :class:`igljoin.JoinResult` holds what they return
and :class:`igljoin.JoinSolver` calls them once per solve.

* :func:`guest_maps` — per-vertex strain and non-rigid displacement of a
  deformed guest;
* :func:`weld_metrics` — counts of a welded mesh and its self-intersections
  near the seams;
* :func:`combined_gap` — the seam gap over several seams.
"""

from __future__ import annotations

from collections.abc import Sequence

import igl
import numpy as np

from . import metrics
from .mesh import Mesh
from .metrics import SELF_INTERSECTION_RINGS
from .weld import Welded

__all__ = ["SELF_INTERSECTION_RINGS", "guest_maps", "weld_metrics", "combined_gap"]


def guest_maps(rest_V: np.ndarray, guest: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex strain and non-rigid displacement of the deformed guest.

    Taken from the guest's ``strain`` and ``displacement`` vertex attributes
    when it has them, else measured against the rest positions as the join
    measures them.

    Parameters
    ----------
    rest_V : ndarray, shape (n_g, 3)
        The guest at rest (same vertices and faces as ``guest``).
    guest : Mesh
        The deformed guest.

    Returns
    -------
    strain, displacement : ndarray, shape (n_g,)
        :func:`igljoin.metrics.vertex_strain` and
        :func:`igljoin.metrics.nonrigid_displacement`.
    """
    attrs = guest.vertex_attributes
    X, F = guest.V, guest.F
    if "strain" in attrs:
        strain = np.asarray(attrs["strain"], dtype=np.float64)
    else:
        E = np.asarray(igl.edges(F), dtype=np.int64)
        strain = metrics.vertex_strain(E, metrics.edge_strain(rest_V, X, E), len(X))
    if "displacement" in attrs:
        disp = np.asarray(attrs["displacement"], dtype=np.float64)
    else:
        disp = metrics.nonrigid_displacement(rest_V, X)
    return strain, disp


def _nearest_seams(
    points: np.ndarray, host_V: np.ndarray, host_curves: Sequence[np.ndarray]
) -> np.ndarray:
    """Index of the host curve nearest to each point (``points`` (p, 3) -> (p,))."""
    if not len(points) or len(host_curves) < 2:
        return np.zeros(len(points), dtype=np.int64)
    dist = np.stack(
        [
            np.linalg.norm(points[:, None, :] - host_V[hc][None, :, :], axis=2).min(axis=1)
            for hc in host_curves
        ],
        axis=1,
    )
    return np.argmin(dist, axis=1)


def weld_metrics(
    welded: Welded,
    host_V: np.ndarray,
    host_curves: Sequence[np.ndarray],
    rings: int = SELF_INTERSECTION_RINGS,
) -> dict:
    """Counts of a welded join and its self-intersections near the seams.

    Parameters
    ----------
    welded : Welded
    host_V : ndarray, shape (n_h, 3)
        The host's vertices (the first ``n_h`` of the welded mesh).
    host_curves : sequence of ndarray of int64
        Each seam's host curve (to say which seam a pair is nearest to).
    rings : int
        Faces of the welded mesh within this many rings of the seam are
        tested against each other (:func:`igljoin.metrics.ring_band`).

    Returns
    -------
    dict
        ``{"weld": {...}, "self_intersections": {...}}``, plain JSON:
        ``weld`` holds ``ok`` and the counts of :meth:`Welded.summary`;
        ``self_intersections`` holds ``pairs`` (intersecting face pairs),
        ``host_guest``, ``guest_guest``, ``host_host`` (the same pairs by
        the faces' sides), ``faces_tested``, ``rings``, ``per_seam`` (the
        pairs by the seam nearest to them) and ``centres`` (per seam, the
        mean centre of those pairs, or None).
    """
    F = welded.mesh.F
    band = metrics.ring_band(F, welded.seam, rings)
    pairs = metrics.self_intersections(welded.mesh.V, F, band)
    sides = welded.label[pairs].sum(axis=1)  # 0 host-host, 1 host-guest, 2 guest-guest
    centres = welded.mesh.V[F[pairs]].mean(axis=(1, 2))  # (p, 3): each pair's centre
    where = _nearest_seams(centres, host_V, host_curves)
    k = len(host_curves)
    return {
        "weld": {"ok": True, **welded.summary()},
        "self_intersections": {
            "pairs": int(len(pairs)),
            "host_guest": int((sides == 1).sum()),
            "guest_guest": int((sides == 2).sum()),
            "host_host": int((sides == 0).sum()),
            "faces_tested": int(band.sum()),
            "rings": int(rings),
            # where: the pairs by the seam nearest to them, and per seam the mean
            # centre of its pairs (None without a pair)
            "per_seam": [int(c) for c in np.bincount(where, minlength=k)],
            "centres": [
                centres[where == i].mean(axis=0).tolist() if (where == i).any() else None
                for i in range(k)
            ],
        },
    }


def combined_gap(gaps: list[dict], counts: list[int]) -> dict:
    """Seam gap over several seams: largest maximum, mean over all seam vertices.

    Parameters
    ----------
    gaps : list of dict
        Each seam's :func:`igljoin.metrics.seam_gap` (``max``, ``mean``,
        ``relative_max``, ``relative_mean``).
    counts : list of int
        Each seam's number of guest seam vertices (the weights of the means).

    Returns
    -------
    dict
        The same keys over all seams; a single seam's dict as it is.
    """
    if len(gaps) == 1:
        return gaps[0]
    w = np.asarray(counts, dtype=np.float64) / float(sum(counts))
    return {
        "max": max(g["max"] for g in gaps),
        "mean": float(sum(wi * g["mean"] for wi, g in zip(w, gaps))),
        "relative_max": max(g["relative_max"] for g in gaps),
        "relative_mean": float(sum(wi * g["relative_mean"] for wi, g in zip(w, gaps))),
    }
