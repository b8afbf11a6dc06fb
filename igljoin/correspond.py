"""Point correspondence between the guest and host curves (paper §4.1).

Each guest curve vertex ``b`` is mapped to the host curve point ``p`` with the
same normalised arc length (Eq. 1), and each host curve vertex ``q`` is
mapped to a guest curve point ``a``; unless a guest vertex already lies
within a small tolerance of ``a``, a new guest vertex is inserted there,
splitting the boundary triangle. Host curve vertices are therefore hit
exactly by guest seam vertices.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .boundary import SelectedCurve
from .errors import CurveError
from .polyline import arc_length_parameters, polyline_length, segment_lengths

__all__ = [
    "Correspondence",
    "pair_curves",
    "pair_seams",
    "correspond",
    "curve_points_at",
    "rigid_fit",
    "rigid_fit_to",
    "rigid_reference",
    "RigidReference",
    "split_boundary_faces",
]

_FIT_SAMPLES = 128


@dataclass(frozen=True)
class Correspondence:
    """The refined guest and the hard constraints of the join.

    Attributes
    ----------
    V : ndarray, shape (n + k, 3)
        Rest positions of the refined guest: original vertices first, the
        ``k`` inserted seam vertices after, in order of insertion.
    F : ndarray of int64, shape (m', 3)
        Faces of the refined guest (split boundary triangles replaced by fans).
    face_parent : ndarray of int64, shape (m',)
        Original guest face each refined face comes from.
    n_original : int
        Number of original guest vertices ``n``.
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order (indices into ``V``).
    targets : ndarray, shape (s, 3)
        Where each seam vertex must go on the host curve.
    seam_t : ndarray, shape (s,)
        Normalised arc-length parameter of each seam vertex.
    host_hit : ndarray of int64, shape (h,)
        For each host curve vertex, the position in ``seam`` of the guest
        vertex that lands on it exactly.
    host_edge : ndarray of int64, shape (s,)
        For each seam vertex, the host curve segment it lands on (segment
        ``j`` joins host curve vertices ``j`` and ``j + 1``).
    host_edge_t : ndarray, shape (s,)
        Position within that segment, in ``[0, 1)``.
    inserted_from : ndarray of int64, shape (k, 2)
        Guest edge (original vertex ids) each inserted vertex splits.
    inserted_t : ndarray, shape (k,)
        Position of each inserted vertex along that edge, in ``(0, 1)``.
    """

    V: np.ndarray
    F: np.ndarray
    face_parent: np.ndarray
    n_original: int
    seam: np.ndarray
    targets: np.ndarray
    seam_t: np.ndarray
    host_hit: np.ndarray
    host_edge: np.ndarray
    host_edge_t: np.ndarray
    inserted_from: np.ndarray
    inserted_t: np.ndarray


def curve_points_at(P: np.ndarray, t_vertices: np.ndarray, t: np.ndarray, closed: bool):
    """Points of a polyline at normalised arc-length parameters.

    Parameters
    ----------
    P : ndarray, shape (k, 3)
        Polyline vertices.
    t_vertices : ndarray, shape (k,)
        Their parameters (from :func:`arc_length_parameters`).
    t : ndarray, shape (q,)
        Query parameters in ``[0, 1]``.
    closed : bool

    Returns
    -------
    points : ndarray, shape (q, 3)
    segment : ndarray of int64, shape (q,)
        Segment index ``j`` (from vertex ``j`` to ``j + 1``, wrapping when closed).
    frac : ndarray, shape (q,)
        Position within the segment in ``[0, 1)``.
    """
    k = len(P)
    ends = np.append(t_vertices, 1.0) if closed else t_vertices
    nseg = k if closed else k - 1
    seg = np.clip(np.searchsorted(ends, t, side="right") - 1, 0, nseg - 1)
    t0, t1 = ends[seg], ends[seg + 1]
    span = np.where(t1 > t0, t1 - t0, 1.0)
    frac = np.clip((t - t0) / span, 0.0, 1.0)
    nxt = (seg + 1) % k
    points = P[seg] * (1.0 - frac)[:, None] + P[nxt] * frac[:, None]
    # a parameter that falls on the segment's far end belongs to the next segment
    wrap = frac >= 1.0
    if wrap.any():
        seg = seg.copy()
        frac = frac.copy()
        seg[wrap] = nxt[wrap] if closed else seg[wrap]
        frac[wrap] = 0.0 if closed else 1.0
    return points, seg, frac


def _resample(P: np.ndarray, closed: bool, n: int) -> np.ndarray:
    t, _ = arc_length_parameters(P, closed)
    q = np.arange(n) / n if closed else np.linspace(0.0, 1.0, n)
    return curve_points_at(P, t, q, closed)[0]


def _rigid_residuals(X: np.ndarray, Ys: np.ndarray) -> np.ndarray:
    """Procrustes residual (proper rotation) of each ``Ys[i]`` fitted onto ``X``.

    Both are centred and scaled to unit RMS radius, so curves of different
    lengths compare by shape. ``X`` has shape (s, 3), ``Ys`` (c, s, 3).
    """
    X = X - X.mean(axis=0)
    X = X / max(np.sqrt((X**2).sum() / len(X)), 1e-300)
    Ys = Ys - Ys.mean(axis=1, keepdims=True)
    Ys = Ys / np.maximum(np.sqrt((Ys**2).sum(axis=(1, 2)) / Ys.shape[1]), 1e-300)[:, None, None]
    H = np.einsum("csi,sj->cij", Ys, X)
    sv = np.linalg.svd(H, compute_uv=False)
    det = np.sign(np.linalg.det(H))
    trace = sv[:, 0] + sv[:, 1] + det * sv[:, 2]
    return (X**2).sum() + (Ys**2).sum(axis=(1, 2)) - 2.0 * trace


def _best_start(X: np.ndarray, Vg: np.ndarray, g: SelectedCurve, fixed: bool):
    """Best rigid-fit start vertex of the closed guest curve ``g`` against samples ``X``.

    Coarse search: cyclic shifts of one resampling of the guest curve; then the
    guest vertices nearest the best shift (in arc length) are compared exactly.
    Returns ``(residual, shift, g)`` with ``shift`` a vertex offset along ``g``.
    """
    k = len(g.indices)
    if fixed:
        Y = _resample(Vg[g.indices], True, _FIT_SAMPLES)[None]
        return float(_rigid_residuals(X, Y)[0]), 0, g
    Y = _resample(Vg[g.indices], True, _FIT_SAMPLES)
    best = _best_cyclic_shift(X, Y)
    t, _ = arc_length_parameters(Vg[g.indices], True)
    near = int(np.argmin(np.abs(((t - best / _FIT_SAMPLES) + 0.5) % 1.0 - 0.5)))
    shifts = (near + np.arange(-3, 4)) % k
    Ys = _resample_shifted(Vg[g.indices], shifts, _FIT_SAMPLES)
    res = _rigid_residuals(X, Ys)
    j = _first_minimum(res)
    return float(res[j]), int(shifts[j]), g


def _cyclic_shifts(Y: np.ndarray, shifts: np.ndarray | None = None) -> np.ndarray:
    """Cyclic shifts of a sample array, ``out[c] = np.roll(Y, -shifts[c], axis=0)``.

    Parameters
    ----------
    Y : ndarray, shape (s, 3)
    shifts : ndarray of int, shape (c,), optional
        Shifts to take; all ``s`` of them (``0 .. s - 1``) by default.

    Returns
    -------
    ndarray, shape (c, s, 3)
    """
    s = len(Y)
    shifts = np.arange(s) if shifts is None else np.asarray(shifts)
    return Y[(shifts[:, None] + np.arange(s)[None, :]) % s]


def _best_cyclic_shift(X: np.ndarray, Y: np.ndarray) -> int:
    """``_first_minimum(_rigid_residuals(X, _cyclic_shifts(Y)))``, evaluated mostly in bulk.

    All shifts are estimated at once (:func:`_shift_estimates`); only those
    that can still be the first minimum (:func:`_shifts_to_fit`) are fitted
    by :func:`_rigid_residuals`, so the returned shift is the one it picks.

    Parameters
    ----------
    X, Y : ndarray, shape (s, 3)
        Host and guest samples.

    Returns
    -------
    int
        The shift ``c`` (``np.roll(Y, -c, axis=0)``) chosen.
    """
    estimated = _shift_estimates(X, Y)
    if estimated is None:
        return _first_minimum(_rigid_residuals(X, _cyclic_shifts(Y)))
    keep = _shifts_to_fit(*estimated)
    return int(keep[_first_minimum(_rigid_residuals(X, _cyclic_shifts(Y, keep)))])


def _shift_estimates(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The residual of every cyclic shift of ``Y`` fitted onto ``X``, and how far off it may be.

    Every cyclic shift of ``Y`` has the same centroid and radius, so the
    cross covariances of all shifts are one circular cross-correlation (FFT)
    and the residuals follow from one batched SVD. They differ from
    :func:`_rigid_residuals` by rounding, except that the determinant of a
    nearly singular cross covariance may come out with the other sign, which
    moves the trace by twice its smallest singular value and the residual by
    twice that.

    Parameters
    ----------
    X, Y
        As in :func:`_best_cyclic_shift`.

    Returns
    -------
    estimate : ndarray, shape (s,)
        Residual of each shift ``c`` (``np.roll(Y, -c, axis=0)``).
    spread : ndarray, shape (s,)
        Bound on the difference from :func:`_rigid_residuals`.
    or None
        If an estimate is not finite.
    """
    s = len(Y)
    Xc = X - X.mean(axis=0)
    Xc = Xc / max(np.sqrt((Xc**2).sum() / s), 1e-300)
    Yc = Y - Y.mean(axis=0)
    Yc = Yc / max(np.sqrt((Yc**2).sum() / s), 1e-300)
    # H[c, i, j] = sum_t Yc[(t + c) % s, i] * Xc[t, j], a circular cross-correlation
    spec = np.fft.rfft(Yc, axis=0)[:, :, None] * np.conj(np.fft.rfft(Xc, axis=0))[:, None, :]
    H = np.fft.irfft(spec, n=s, axis=0)
    sv = np.linalg.svd(H, compute_uv=False)
    det = np.linalg.det(H)
    trace = sv[:, 0] + sv[:, 1] + np.sign(det) * sv[:, 2]
    estimate = (Xc**2).sum() + (Yc**2).sum() - 2.0 * trace
    if not np.isfinite(estimate).all():
        return None
    # a determinant this small against the largest singular value cubed may have either sign
    unsure = np.abs(det) <= 1e-10 * sv[:, 0] ** 3
    # 1e-7 relative: rounding differences are near 1e-13 here (|residual| <= 4 s), far less
    spread = 1e-7 * np.maximum(np.abs(estimate), 1.0) + 4.0 * sv[:, 2] * unsure
    return estimate, spread


def _shifts_to_fit(estimate: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """The candidates that can still be :func:`_first_minimum` of the exact values.

    Parameters
    ----------
    estimate, spread : ndarray, shape (c,)
        Each exact value lies within ``estimate ± spread``.

    Returns
    -------
    ndarray of int64, shape (k,)
        Ascending indices of every candidate whose value may be the minimum
        or within :func:`_first_minimum`'s tie band above it.
    """
    # the minimum exact value lies between ``floor`` and ``reach``
    reach = float((estimate + spread).min())
    floor = float((estimate - spread).min())
    # _first_minimum's tie band is 1e-9 relative to that minimum; 1e-8 covers it
    band = 1e-8 * max(abs(reach), abs(floor), 1.0)
    return np.flatnonzero(estimate - spread <= reach + band)


def _resample_shifted(P: np.ndarray, shifts: np.ndarray, n: int) -> np.ndarray:
    """Resamplings of a closed polyline started at several of its vertices.

    ``out[c]`` equals ``_resample(P[np.roll(np.arange(k), -shifts[c])], True, n)``
    value for value: each shift repeats that function's arithmetic in the
    same order, for all shifts at once.

    Parameters
    ----------
    P : ndarray, shape (k, 3)
        Closed polyline vertices.
    shifts : ndarray of int, shape (c,)
        Start vertex of each resampling, in ``[0, k)``.
    n : int
        Samples per resampling.

    Returns
    -------
    ndarray, shape (c, n, 3)
    """
    k = len(P)
    shifts = np.asarray(shifts, dtype=np.int64)
    c = shifts.size
    walk = (shifts[:, None] + np.arange(k)[None, :]) % k  # (c, k) vertex of each position
    seg = segment_lengths(P, True)[walk]
    cum = np.concatenate([np.zeros((c, 1)), np.cumsum(seg, axis=1)], axis=1)
    if not (cum[:, -1] > 0).all():
        return np.stack([_resample(P[row], True, n) for row in walk])
    ends = np.concatenate([cum[:, :k] / cum[:, -1:], np.ones((c, 1))], axis=1)  # (c, k + 1)
    q = np.arange(n) / n
    # searchsorted(ends[r], q, "right") counts the ends <= q[j]; an end e is <= q[j]
    # exactly when j >= searchsorted(q, e, "left"), so the counts are running sums
    first = np.searchsorted(q, ends.reshape(-1), side="left").reshape(c, k + 1)
    hits = np.bincount((first + (n + 1) * np.arange(c)[:, None]).reshape(-1), minlength=c * (n + 1))
    count = np.cumsum(hits.reshape(c, n + 1), axis=1)[:, :n]
    at = np.clip(count - 1, 0, k - 1)
    t0 = np.take_along_axis(ends, at, axis=1)
    t1 = np.take_along_axis(ends, at + 1, axis=1)
    span = np.where(t1 > t0, t1 - t0, 1.0)
    frac = np.clip((q - t0) / span, 0.0, 1.0)
    here = np.take_along_axis(walk, at, axis=1)
    ahead = np.take_along_axis(walk, (at + 1) % k, axis=1)
    return P[here] * (1.0 - frac)[:, :, None] + P[ahead] * frac[:, :, None]


def _first_minimum(values: np.ndarray) -> int:
    """Index of the first value within rounding of the minimum.

    Symmetric curves (an ellipse fits itself after half a turn) tie up to
    rounding; taking the first of the tied candidates keeps the choice the same
    when the inputs are moved rigidly.
    """
    low = float(values.min())
    return int(np.flatnonzero(values <= low + 1e-9 * max(abs(low), 1.0))[0])


def pair_curves(
    Vh: np.ndarray,
    host: SelectedCurve,
    Vg: np.ndarray,
    guest: SelectedCurve,
    *,
    guest_start_given: bool,
) -> tuple[SelectedCurve, SelectedCurve, dict]:
    """Orient the two curves and choose the guest's start.

    For closed curves the guest runs against the host's face-induced
    direction, so that the welded result is consistently oriented. When no
    guest start was given, the start is the one whose resampled curve fits
    the host curve best by a rigid motion (independent of where the guest
    happens to be placed).

    Parameters
    ----------
    Vh, Vg : ndarray, shape (n_h, 3), (n_g, 3)
        Host and guest vertices.
    host, guest : SelectedCurve
    guest_start_given : bool
        Keep the guest's first vertex as its start.

    Returns
    -------
    host, guest : SelectedCurve
        Paired curves: guest vertex 0 corresponds to host vertex 0.
    info : dict
        ``fit_residual`` (best normalised residual), ``reverse_fit_residual``
        (the best residual had the guest run the other way).
    """
    if host.closed != guest.closed:
        kinds = {True: "closed", False: "open"}
        raise CurveError(
            f"host_curve is {kinds[host.closed]} but guest_curve is {kinds[guest.closed]}; "
            "both curves must be closed loops or both open paths (give start and end on both)"
        )
    for name, V, c in (("host_curve", Vh, host), ("guest_curve", Vg, guest)):
        if polyline_length(V[c.indices], c.closed) <= 0.0:
            raise CurveError(
                f"{name} has length zero (its vertices coincide); remove duplicate vertices "
                "(igljoin.clean) or pick another curve"
            )
    info: dict = {}
    if not host.closed:
        return host, guest, info
    if guest.forward == host.forward:
        guest = guest.reversed()
    X = _resample(Vh[host.indices], True, _FIT_SAMPLES)
    candidates = {}
    for label, g in (("paired", guest), ("reverse", guest.reversed())):
        candidates[label] = _best_start(X, Vg, g, fixed=guest_start_given)
    residual, shift, guest = candidates["paired"]
    info["fit_residual"] = residual
    info["reverse_fit_residual"] = candidates["reverse"][0]
    return host, guest.rolled(shift), info


def rigid_fit(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proper rotation ``R`` (3, 3) and translation ``t`` (3,) minimising ‖A Rᵀ + t − B‖.

    ``A`` and ``B`` have shape (q, 3) (Kabsch, without reflection):
    ``rigid_fit_to(rigid_reference(A), B)``.
    """
    return rigid_fit_to(rigid_reference(A), B)


class RigidReference(NamedTuple):
    """The side of a rigid fit that does not depend on the target (:func:`rigid_reference`).

    Attributes
    ----------
    centroid : ndarray, shape (3,)
        Mean of the positions.
    centred : ndarray, shape (q, 3)
        The positions less their mean.
    """

    centroid: np.ndarray
    centred: np.ndarray


def rigid_reference(A: np.ndarray) -> RigidReference:
    """The mean of the positions ``A`` (q, 3) and the positions less it.

    Made once, it fits ``A`` to any number of targets (:func:`rigid_fit_to`).
    """
    ca = A.mean(axis=0)
    return RigidReference(ca, A - ca)


def rigid_fit_to(reference: RigidReference, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rigid_fit` of the positions of ``reference`` onto ``B`` (q, 3).

    Parameters
    ----------
    reference : RigidReference
        ``rigid_reference(A)``.
    B : ndarray, shape (q, 3)

    Returns
    -------
    R : ndarray, shape (3, 3)
        Proper rotation.
    t : ndarray, shape (3,)
        Translation: ``A Rᵀ + t`` is the fit of ``A`` onto ``B``.
    """
    ca, centred = reference
    cb = B.mean(axis=0)
    H = centred.T @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, cb - ca @ R.T


def _fit_residual(X: np.ndarray, Y: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Summed squared distances ``‖Y[c] Rᵀ + t − X‖²`` for each candidate ``c``; ``Y`` (c, q, 3)."""
    D = Y @ R.T + t - X
    return np.einsum("cqj,cqj->c", D, D)


def pair_seams(
    Vh: np.ndarray,
    hosts: list[SelectedCurve],
    Vg: np.ndarray,
    guests: list[SelectedCurve],
    *,
    guest_starts_given: list[bool],
    rounds: int = 10,
) -> list[tuple[SelectedCurve, SelectedCurve, dict]]:
    """Pair the curves of several seams of one guest, with consistent starts.

    Each seam is first paired on its own (:func:`pair_curves`). With several
    seams, the starts of closed guest curves without a given start are then
    chosen together: one rigid motion of the guest is fitted to all seams at
    once and each such curve is started where it fits the host curve best
    under that motion, alternately, until the starts no longer change. A
    guest whose ends are nearly round (a graft) is so not twisted between
    its seams, which fitting each end on its own does not prevent. The
    choice does not depend on where the guest is placed.

    Parameters
    ----------
    Vh, Vg : ndarray, shape (n_h, 3), (n_g, 3)
    hosts, guests : list of SelectedCurve
        The curves of each seam.
    guest_starts_given : list of bool
        Keep the guest curve's first vertex as its start, per seam.
    rounds : int
        Most fit/start alternations.

    Returns
    -------
    list of (SelectedCurve, SelectedCurve, dict)
        Per seam as :func:`pair_curves` returns; ``info`` gains
        ``joint_fit_residual`` (RMS distance, in the mesh's length unit, of
        all resampled guest curves from their host curves after the common
        rigid fit) when several seams were paired together.
    """
    paired = [
        pair_curves(Vh, h, Vg, g, guest_start_given=given)
        for h, g, given in zip(hosts, guests, guest_starts_given)
    ]
    if len(paired) < 2:
        return paired
    free = [
        i
        for i, ((h, _, _), given) in enumerate(zip(paired, guest_starts_given))
        if h.closed and not given
    ]
    X = [_resample(Vh[h.indices], h.closed, _FIT_SAMPLES) for h, _, _ in paired]
    guest = [g for _, g, _ in paired]
    # closed free curves: every cyclic roll of one resampling is a candidate start
    base = {i: _resample(Vg[guest[i].indices], True, _FIT_SAMPLES) for i in free}
    rolls = {i: _cyclic_shifts(base[i]) for i in free}
    current = [_resample(Vg[g.indices], g.closed, _FIT_SAMPLES) for g in guest]
    for _ in range(rounds if free else 0):
        R, t = rigid_fit(np.vstack(current), np.vstack(X))
        changed = False
        for i in free:
            g = guest[i]
            coarse = _first_minimum(_fit_residual(X[i], rolls[i], R, t))
            # refine: the guest vertices nearest that roll in arc length, compared exactly
            tv, _ = arc_length_parameters(Vg[g.indices], True)
            k = len(g.indices)
            near = int(np.argmin(np.abs(((tv - coarse / _FIT_SAMPLES) + 0.5) % 1.0 - 0.5)))
            shifts = (near + np.arange(-3, 4)) % k
            cand = _resample_shifted(Vg[g.indices], shifts, _FIT_SAMPLES)
            j = int(shifts[_first_minimum(_fit_residual(X[i], cand, R, t))])
            if j:
                guest[i] = g.rolled(j)
                base[i] = _resample(Vg[guest[i].indices], True, _FIT_SAMPLES)
                rolls[i] = _cyclic_shifts(base[i])
                current[i] = base[i]
                changed = True
        if not changed:
            break
    R, t = rigid_fit(np.vstack(current), np.vstack(X))
    D = np.vstack(current) @ R.T + t - np.vstack(X)
    rms = float(np.sqrt(np.einsum("ij,ij->i", D, D).mean()))
    return [(h, g, {**info, "joint_fit_residual": rms}) for (h, _, info), g in zip(paired, guest)]


def correspond(
    Vg: np.ndarray,
    Fg: np.ndarray,
    guest: SelectedCurve,
    Vh: np.ndarray,
    host: SelectedCurve,
    *,
    snap_fraction: float = 0.1,
) -> Correspondence:
    """Map the curves onto each other and insert host points into the guest.

    Parameters
    ----------
    Vg : ndarray, shape (n, 3)
    Fg : ndarray of int64, shape (m, 3)
        Guest mesh.
    guest : SelectedCurve
        Guest curve, paired with ``host`` by :func:`pair_curves`.
    Vh : ndarray, shape (n_h, 3)
        Host vertices.
    host : SelectedCurve
    snap_fraction : float
        A host point whose image on the guest curve is within this fraction
        of the local guest edge length of an existing guest vertex is
        matched to that vertex instead of inserting a new one.

    Returns
    -------
    Correspondence
    """
    closed = host.closed
    U = guest.indices
    P_u = Vg[U]
    P_v = Vh[host.indices]
    t_u, _ = arc_length_parameters(P_u, closed)
    t_v, _ = arc_length_parameters(P_v, closed)
    n_u, n_v = len(U), len(host.indices)

    # host vertex j lands on the guest curve at t_v[j]: nearest guest vertex in parameter space
    ends_u = np.append(t_u, 1.0) if closed else t_u
    seg = np.clip(np.searchsorted(ends_u, t_v, side="right") - 1, 0, len(ends_u) - 2)
    seg_len = ends_u[seg + 1] - ends_u[seg]
    frac = np.where(seg_len > 0, (t_v - ends_u[seg]) / np.where(seg_len > 0, seg_len, 1.0), 0.0)
    near = np.where(frac < 0.5, seg, seg + 1)
    near_dist = np.minimum(frac, 1.0 - frac)
    if closed:
        near = near % n_u
    snap = near_dist <= snap_fraction
    if not closed:
        snap[0] = snap[-1] = True  # start meets start and end meets end
        near[0], near[-1] = 0, n_u - 1
    # at most one host vertex per guest vertex: keep the closest, insert the others
    order = np.lexsort((near_dist, near))
    dup = np.zeros(n_v, dtype=bool)
    ns = near[order]
    dup[order[1:]] = (ns[1:] == ns[:-1]) & snap[order[1:]] & snap[order[:-1]]
    if not closed:
        dup[[0, n_v - 1]] = False
    snap &= ~dup
    # guest vertex snapped to a host vertex -> exact target
    guest_hit = np.full(n_u, -1, dtype=np.int64)
    guest_hit[near[snap]] = np.flatnonzero(snap)

    insert = np.flatnonzero(~snap)
    ins_seg = seg[insert]
    ins_frac = np.clip(frac[insert], 1e-9, 1.0 - 1e-9)

    # merged seam: original guest curve vertices and inserted ones, sorted by parameter
    t_all = np.concatenate([t_u, t_v[insert]])
    n0 = len(Vg)
    ids = np.concatenate([U, n0 + np.arange(insert.size)])
    order = np.argsort(t_all, kind="stable")
    seam = ids[order]
    seam_t = t_all[order]

    # targets: host vertices hit exactly; other guest vertices at their arc-length image
    host_of = np.concatenate([guest_hit, insert])[order]
    targets, h_edge, h_frac = curve_points_at(P_v, t_v, seam_t, closed)
    exact = host_of >= 0
    targets[exact] = P_v[host_of[exact]]
    h_edge[exact] = host_of[exact]
    h_frac[exact] = 0.0
    if not closed:
        last = h_edge == n_v - 1
        h_edge[last], h_frac[last] = n_v - 2, 1.0
    host_hit = np.empty(n_v, dtype=np.int64)
    host_hit[host_of[exact]] = np.flatnonzero(exact)

    a = U[ins_seg]
    b = U[(ins_seg + 1) % n_u]
    new_V = Vg[a] * (1.0 - ins_frac)[:, None] + Vg[b] * ins_frac[:, None]
    V = np.vstack([Vg, new_V])
    F, parent = split_boundary_faces(Fg, a, b, ins_frac, n0)
    return Correspondence(
        V=V,
        F=F,
        face_parent=parent,
        n_original=n0,
        seam=seam,
        targets=targets,
        seam_t=seam_t,
        host_hit=host_hit,
        host_edge=h_edge,
        host_edge_t=h_frac,
        inserted_from=np.stack([a, b], axis=1) if insert.size else np.zeros((0, 2), np.int64),
        inserted_t=ins_frac,
    )


def split_boundary_faces(F, a, b, frac, n0):
    """Replace each boundary face whose edge (a, b) received new vertices by a fan.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
    a, b : ndarray of int64, shape (k,)
        Guest edge split by each inserted vertex ``n0 + i``.
    frac : ndarray, shape (k,)
        Position of each inserted vertex from ``a`` to ``b``.
    n0 : int
        Number of original vertices.

    Returns
    -------
    F : ndarray of int64, shape (m + k, 3)
    parent : ndarray of int64, shape (m + k,)
    """
    m = len(F)
    parent = np.arange(m, dtype=np.int64)
    if a.size == 0:
        return F.copy(), parent
    n = int(max(F.max(), a.max(), b.max())) + 1
    order, skey = _directed_edges_at(F, a, b, n)

    def find(u, v):
        q = u * n + v
        pos = np.clip(np.searchsorted(skey, q), 0, len(skey) - 1)
        hit = skey[pos] == q
        return np.where(hit, order[pos], -1)

    fwd = find(a, b)
    bwd = find(b, a)
    if ((fwd < 0) & (bwd < 0)).any():
        raise CurveError(
            "guest_curve: a curve edge belongs to no face; the curve must follow mesh edges"
        )
    # group inserted vertices by the half-edge they split, ordered along it
    he = np.where(fwd >= 0, fwd, bwd)
    along = np.where(fwd >= 0, frac, 1.0 - frac)
    grp = np.lexsort((along, he))
    he_sorted = he[grp]
    starts = np.flatnonzero(np.r_[True, he_sorted[1:] != he_sorted[:-1]])
    stops = np.r_[starts[1:], len(grp)]
    fans = _fans_of_single_splits(F, grp, he_sorted, starts, stops, n0)
    if fans is None:
        fans = _fans_split_in_turn(F, grp, he_sorted, starts, stops, n0)
    touched, new_F, new_parent = fans
    keep = np.ones(m, dtype=bool)
    keep[touched] = False
    return np.vstack([F[keep], new_F]), np.concatenate([parent[keep], new_parent])


def _directed_edges_at(F, a, b, n):
    """The half-edges of ``F`` (m, 3) sorted by ``start * n + end``, as the split searches them.

    Returns ``order`` (each one's half-edge ``3 f + e``, running ``F[f, e] ->
    F[f, (e + 1) % 3]``) and ``skey`` (their keys, ascending). Only the faces
    with two corners among the split edges' ends ``a``, ``b`` (k,) can hold a
    split half-edge, so only theirs are sorted. Every face's half-edges are
    sorted instead where there are none (the split's search then finds its
    missing edges among all of them and reports them, as an empty array
    could not) or two of them run the same way (the order among equal keys
    is then the sort's of all of them, as before).
    """
    on = np.zeros(n, dtype=bool)
    on[a] = True
    on[b] = True
    near = np.flatnonzero(on[F].sum(axis=1) >= 2)
    G = F[near]
    key = G.reshape(-1) * n + G[:, [1, 2, 0]].reshape(-1)
    order = np.argsort(key)
    skey = key[order]
    if near.size and not (skey[1:] == skey[:-1]).any():
        return 3 * near[order // 3] + order % 3, skey
    key = F.reshape(-1) * n + F[:, [1, 2, 0]].reshape(-1)
    order = np.argsort(key)
    return order, key[order]


def _fans_of_single_splits(F, grp, he_sorted, starts, stops, n0):
    """The fans of :func:`split_boundary_faces` when each split face has one split edge.

    Builds the same triangles in the same order as :func:`_fans_split_in_turn`
    (one fan per split half-edge, in half-edge order, each running along the
    edge), without a loop over the faces.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
    grp : ndarray of int64, shape (k,)
        Inserted vertices (offsets from ``n0``) grouped by half-edge, ordered along it.
    he_sorted : ndarray of int64, shape (k,)
        Half-edge ``3 f + e`` split by each of them.
    starts, stops : ndarray of int64, shape (g,)
        Each half-edge's run in ``grp``.
    n0 : int

    Returns
    -------
    touched : ndarray of int64, shape (g,)
        Split faces, ascending.
    new_F : ndarray of int64, shape (k + g, 3)
    new_parent : ndarray of int64, shape (k + g,)
    or None
        When a face has two split edges, repeats a vertex, or shares a
        directed edge with another split face (the faces are then split in
        turn, where one split may land in another's fan).
    """
    face, edge = np.divmod(he_sorted[starts], 3)
    tri = F[face].astype(np.int64)
    if (np.diff(face) <= 0).any():
        return None
    if ((tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 2] == tri[:, 0])).any():
        return None
    n = int(tri.max()) + 1
    directed = np.sort((tri * n + tri[:, [1, 2, 0]]).reshape(-1))
    if (directed[1:] == directed[:-1]).any():
        return None
    g = face.size
    rows = np.arange(g)
    u = tri[rows, edge]
    v = tri[rows, (edge + 1) % 3]
    w = tri[rows, (edge + 2) % 3]
    count = stops - starts
    # fan j takes rows starts[j] + j .. stops[j] + j: (u, x1, w), (x1, x2, w), ..., (xc, v, w)
    first = starts + rows
    last = stops + rows
    total = len(grp) + g
    p = np.empty(total, dtype=np.int64)
    q = np.empty(total, dtype=np.int64)
    inner_p = np.ones(total, dtype=bool)
    inner_p[first] = False
    inner_q = np.ones(total, dtype=bool)
    inner_q[last] = False
    p[first] = u
    p[inner_p] = n0 + grp
    q[last] = v
    q[inner_q] = n0 + grp
    new_F = np.stack([p, q, np.repeat(w, count + 1)], axis=1)
    return face, new_F, np.repeat(face, count + 1)


def _fans_split_in_turn(F, grp, he_sorted, starts, stops, n0):
    """The fans of :func:`split_boundary_faces`, one split half-edge after the other.

    Parameters and returns as :func:`_fans_of_single_splits` (never ``None``).
    A face with two split edges is split again inside the fan made for the
    first (seam-sized loop).
    """
    faces: dict[int, tuple[int, int, int]] = {}
    face_parent: dict[int, int] = {}
    owner: dict[tuple[int, int], int] = {}

    keys = itertools.count()

    def add(tri, par):
        key = next(keys)
        faces[key] = tri
        face_parent[key] = par
        for e in range(3):
            owner[(tri[e], tri[(e + 1) % 3])] = key

    touched = np.unique(he_sorted[starts] // 3)
    for f in touched:
        add(tuple(int(x) for x in F[f]), int(f))
    for s0, s1 in zip(starts, stops):
        f, e = divmod(int(he_sorted[s0]), 3)
        u, v = int(F[f, e]), int(F[f, (e + 1) % 3])
        key = owner[(u, v)]
        tri = faces.pop(key)
        par = face_parent.pop(key)
        r = tri.index(u)
        w = tri[(r + 2) % 3]
        chain = [u, *(n0 + grp[s0:s1]).tolist(), v]
        for p, q in zip(chain[:-1], chain[1:]):
            add((p, q, w), par)
    new_F = np.array(list(faces.values()), dtype=np.int64).reshape(-1, 3)
    new_parent = np.array(list(face_parent.values()), dtype=np.int64)
    return touched, new_F, new_parent
