"""Polylines given as ordered points: segment lengths, total and mean length, arc length.

A polyline is an array ``P`` of shape ``(k, d)`` (``d`` is 3 for mesh
curves, 2 for the phantoms' planar outlines); ``closed`` says whether the
segment from the last point back to the first belongs to it.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "arc_length_parameters",
    "arc_lengths",
    "mean_segment",
    "polyline_length",
    "segment_lengths",
]


def segment_lengths(P: np.ndarray, closed: bool = True) -> np.ndarray:
    """Length of each segment.

    Parameters
    ----------
    P : ndarray, shape (k, d)
    closed : bool

    Returns
    -------
    ndarray, shape (k,) if ``closed`` else (k − 1,)
        ``|P[i + 1] − P[i]|``, the closing segment ``|P[0] − P[k − 1]|`` last.
    """
    P = np.asarray(P)
    Q = np.roll(P, -1, axis=0) if closed else P[1:]
    return np.linalg.norm(Q - P[: len(Q)], axis=1)


def polyline_length(P: np.ndarray, closed: bool = True) -> float:
    """Total length of a polyline ``P`` of shape (k, d) (0 for fewer than two points).

    Examples
    --------
    >>> square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    >>> polyline_length(square), polyline_length(square, closed=False)
    (4.0, 3.0)
    """
    return float(segment_lengths(P, closed).sum())


def mean_segment(P: np.ndarray, closed: bool = True) -> float:
    """Mean segment length of a polyline ``P`` of shape (k, d), k ≥ 2 (the seam's length scale)."""
    return float(segment_lengths(P, closed).mean())


def arc_lengths(P: np.ndarray, closed: bool = True) -> tuple[np.ndarray, float]:
    """Arc length ``s`` (k,) from ``P[0]`` to each vertex of ``P`` (k, d), and the total length.

    Examples
    --------
    >>> square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    >>> s, length = arc_lengths(square)
    >>> s.tolist(), length
    ([0.0, 1.0, 2.0, 3.0], 4.0)
    """
    seg = segment_lengths(P, closed)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    return cum[: len(P)], float(cum[-1])


def arc_length_parameters(P: np.ndarray, closed: bool = True) -> tuple[np.ndarray, float]:
    """Normalised arc-length parameter ``t`` (k,) of each vertex of ``P`` (k, d), and the length.

    Paper Eq. 1: ``t[0] = 0``, increasing; ``t[-1] = 1`` for an open curve
    and ``< 1`` for a closed one (its closing segment ends at 1).
    """
    seg = segment_lengths(P, closed)
    length = float(seg.sum())
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    t = cum[: len(P)] / cum[-1] if length > 0 else np.zeros(len(P))
    if not closed and length > 0:
        t[-1] = 1.0
    return t, length
