"""Join-quality measures: seam gap, crease angle, deformation maps, folds.

Crease angle
    At a host curve vertex ``q`` (hit exactly by a guest seam vertex), take
    the curve tangent ``T``, the host's one-ring normal and the deformed
    guest's one-ring normal there. Each surface's cross-seam direction is its
    tangent perpendicular to ``T`` pointing into that surface (host ``h``,
    guest ``g``). The crease is the angle between ``g`` and ``−h``, the host
    surface continued across the boundary: 0° for a smooth join, 180° for a
    guest folded back onto the host.
"""

from __future__ import annotations

import numpy as np

from .frames import face_normals_areas, seam_frames

__all__ = [
    "area_ratio",
    "edge_strain",
    "crease_angles",
    "seam_gap",
    "folded_pairs",
    "summary",
    "point_polyline_distance",
]


def area_ratio(V0: np.ndarray, V1: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Deformed over rest area of each face (the paper's deformation display).

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
        Rest and deformed positions.
    F : ndarray of int64, shape (m, 3)

    Returns
    -------
    ndarray, shape (m,)
        1 where a face kept its area, > 1 stretched, < 1 shrunk.
    """
    _, a0 = face_normals_areas(V0, F)
    _, a1 = face_normals_areas(V1, F)
    return a1 / np.where(a0 > 0, a0, np.nan)


def edge_strain(V0: np.ndarray, V1: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Relative length change ``(ℓ′ − ℓ)/ℓ`` of each edge ``E`` (shape (e, 2)) -> (e,)."""
    l0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
    l1 = np.linalg.norm(V1[E[:, 0]] - V1[E[:, 1]], axis=1)
    return (l1 - l0) / np.where(l0 > 0, l0, np.nan)


def crease_angles(
    Vh: np.ndarray,
    Fh: np.ndarray,
    host_curve: np.ndarray,
    Vg: np.ndarray,
    Fg: np.ndarray,
    guest_at_host: np.ndarray,
    closed: bool,
) -> np.ndarray:
    """Crease angle in degrees at each host curve vertex.

    Parameters
    ----------
    Vh : ndarray, shape (n_h, 3)
    Fh : ndarray of int64, shape (m_h, 3)
    host_curve : ndarray of int64, shape (k,)
        Ordered host curve vertices.
    Vg : ndarray, shape (n_g, 3)
    Fg : ndarray of int64, shape (m_g, 3)
        Guest surface (deformed, or in place for an uncut reference).
    guest_at_host : ndarray of int64, shape (k,)
        Guest vertex lying on each host curve vertex.
    closed : bool

    Returns
    -------
    ndarray, shape (k,)
    """
    host = seam_frames(Vh, Fh, host_curve, closed)
    guest = seam_frames(Vg, Fg, guest_at_host, closed, curve_points=Vh[host_curve])
    cos = np.einsum("ij,ij->i", guest.inward, -host.inward)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def point_polyline_distance(P: np.ndarray, C: np.ndarray, closed: bool) -> np.ndarray:
    """Distance of each point ``P`` (shape (p, 3)) to the polyline ``C`` (shape (k, 3)).

    Returns shape (p,). Memory is ``p × k``; chunked for long inputs.
    """
    A = C
    B = np.roll(C, -1, axis=0) if closed else C[1:]
    A = A[: len(B)]
    AB = B - A
    ab2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    out = np.empty(len(P))
    chunk = max(1, 2_000_000 // max(len(A), 1))
    for s in range(0, len(P), chunk):
        Q = P[s : s + chunk]
        t = np.clip(np.einsum("pkj,kj->pk", Q[:, None, :] - A[None], AB) / ab2, 0.0, 1.0)
        D = A[None] + t[..., None] * AB[None] - Q[:, None, :]
        out[s : s + chunk] = np.sqrt(np.einsum("pkj,pkj->pk", D, D).min(axis=1))
    return out


def seam_gap(seam_points: np.ndarray, host_points: np.ndarray, closed: bool) -> dict:
    """Distance of the guest seam to the host curve.

    Parameters
    ----------
    seam_points : ndarray, shape (s, 3)
        Deformed guest seam vertices.
    host_points : ndarray, shape (k, 3)
        Host curve polyline.
    closed : bool

    Returns
    -------
    dict
        ``max``, ``mean`` (absolute), ``relative_max``, ``relative_mean``
        (divided by the mean host seam edge).
    """
    d = point_polyline_distance(seam_points, host_points, closed)
    seg = np.roll(host_points, -1, axis=0) - host_points if closed else np.diff(host_points, axis=0)
    mean_edge = float(np.linalg.norm(seg, axis=1).mean())
    return {
        "max": float(d.max()),
        "mean": float(d.mean()),
        "relative_max": float(d.max() / mean_edge),
        "relative_mean": float(d.mean() / mean_edge),
    }


def folded_pairs(V0: np.ndarray, V1: np.ndarray, F: np.ndarray, angle: float = 150.0) -> np.ndarray:
    """Adjacent face pairs whose normals turned against each other.

    A pair counts when the angle between the two faces' normals exceeds
    ``angle`` degrees in the deformed mesh but not in the rest mesh.

    Parameters
    ----------
    V0, V1 : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    angle : float

    Returns
    -------
    ndarray of int64, shape (p, 2)
        Face index pairs.
    """
    m = len(F)
    n = int(F.max()) + 1
    he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    face = np.tile(np.arange(m), 3)
    key = np.minimum(he[:, 0], he[:, 1]) * n + np.maximum(he[:, 0], he[:, 1])
    order = np.argsort(key, kind="stable")
    k = key[order]
    same = np.flatnonzero(k[1:] == k[:-1])
    pairs = np.stack([face[order[same]], face[order[same + 1]]], axis=1)
    if not len(pairs):
        return pairs
    limit = np.cos(np.radians(angle))
    n0, _ = face_normals_areas(V0, F)
    n1, _ = face_normals_areas(V1, F)
    c0 = np.einsum("ij,ij->i", n0[pairs[:, 0]], n0[pairs[:, 1]])
    c1 = np.einsum("ij,ij->i", n1[pairs[:, 0]], n1[pairs[:, 1]])
    return pairs[(c1 < limit) & (c0 >= limit)]


def summary(values: np.ndarray) -> dict:
    """Mean, median, 95th percentile, min and max of finite values, as floats."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": None, "median": None, "p95": None, "min": None, "max": None}
    return {
        "mean": float(v.mean()),
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95)),
        "min": float(v.min()),
        "max": float(v.max()),
    }
