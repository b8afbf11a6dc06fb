"""The surface beside a boundary curve, fitted over a band of stated width.

At each vertex ``q`` of a boundary curve the surface on its one side is
fitted, over the vertices within ``band`` of ``q`` (less along the curve
where the surface bends round it, as at a tube's end: :func:`along_curve_reach`),
as a map ``X(u, v) ≈ q + a u + c v + …`` of the local coordinates ``u``
(along the curve) and ``v`` (into the surface): a quadratic, and three terms
more of the bend along the curve (``u³, u⁴, u²v``) where the band holds
enough vertices. The fit's derivative ``c = ∂X/∂v`` at ``q`` is the
direction in which the surface leaves the curve, measured at the scale of
the band rather than of the triangles at ``q``: a sliver, a very short curve
edge or a zig-zag curve changes it little, because it is a least-squares fit
over every vertex of the band. The fit's residuals give its standard error.

Because the local coordinates are fixed (taken from one configuration),
``c`` is a *linear* function of the vertex positions: :func:`band_fit`
returns that function as a sparse matrix, so the same fit measures a crease
(:mod:`igljoin.crease`) and, applied to the unknown positions, gives the
smooth-join term its rows (:class:`igljoin.terms.SmoothJoinTerm`, mode
``"band"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain

import numba as nb
import numpy as np
import scipy.sparse as sp

from .errors import OptionsError
from .frames import SeamFrames, face_normals_areas, unit, vertex_face_matrix
from .polyline import arc_lengths

__all__ = [
    "BandFit",
    "band_fit",
    "curve_tangents",
    "along_curve_reach",
    "median_edge_near",
    "BAND_EDGES",
]

#: Default band width, in median edge lengths of the surfaces near the curve: wide
#: enough that the fit sees two to three rings of ordinary triangles beyond any sliver
#: row at the curve, narrow enough to stay local on the paper's tubes.
BAND_EDGES = 3.0

#: Size guard of one band fit: the entries of its rows, i.e. the mesh vertices within
#: the band summed over the curve vertices, counted before any array of the fit is
#: made (its work arrays are chunked, :data:`FIT_CHUNK_ENTRIES`, so only its rows grow
#: with the band). A join spends about :data:`_BYTES_PER_ENTRY` bytes per entry on
#: them (the fit, the smooth-join term's copies, the augmented system's matrix and
#: factor, the coarse model's share), so 1e8 entries are about 15 GB on top of the join
#: without them (a tube's seam less than half of that). A 1M-vertex tube under the paper's
#: host has 5.5e7. Change with ``igljoin.bandfit.MAX_FIT_ENTRIES``.
MAX_FIT_ENTRIES = 100_000_000

#: Bytes a join spends per entry of its band fit (see :data:`MAX_FIT_ENTRIES`): the peak
#: RSS of a set-up and three iterations with the band rows less that of the same join
#: with the one-ring smooth rows (``smooth_mode="robust"``), over the entries the guard
#: counts, measured on the paper's patch and tube at 100k and 300k guest vertices:
#: 113-145 bytes on the patches, where nearly every counted vertex enters the fit,
#: 52-72 on the tubes, where about half of them lie outside the fit's ellipsoid (round
#: the tube) and its rows hold half as many (per entry of the rows themselves about
#: 110-150 on both). 145, the patches' largest, so that the refusal's estimate does not
#: understate on a mesh like the patch (measured on these two phantoms only; a tube's
#: seam is overstated about 2x); 150 had come from the 1M tube before the join's memory
#: was cut (10.5 GB then, 7.75 GB now).
_BYTES_PER_ENTRY = 145

#: Work-array entries (curve vertices × band vertices, padded) of one chunk of a band
#: fit; about 210 bytes each (peak RSS of one fit of the 300k tube's seam at 2¹⁹ and 2²¹
#: entries a chunk), so about 55 MB at a time. Smaller chunks stay in the caches and
#: reuse their memory: the 300k tube's terms took 2.1-2.3 s in chunks of 2¹⁸ entries
#: against 2.6 s in chunks of 2¹⁹, and 2.6-2.8 against 3.4-3.6 s as a process's first;
#: 2¹⁷ was about as fast but left the 100k tube's join 17 MB more at its peak (the
#: allocator keeps smaller blocks), 2¹⁵ slower. Every chunking gives the same floats.
FIT_CHUNK_ENTRIES = 1 << 18

#: A curve whose vertices could not hold more than this many band vertices however wide
#: the band (each has at most every vertex near the curve) is queried once; a longer one
#: is counted first and queried a chunk at a time (the whole curve's lists of band
#: vertices, Python integers, are held only up to this size).
WHOLE_QUERY_ENTRIES = 1 << 19

#: A band vertex whose normal turns more than about 70° from the curve vertex's
#: normal is on another sheet of the surface (the far side of a thin wall or wing).
_SAME_SHEET_COS = 0.35

#: Half-width of a band along a closed curve, as a fraction of the curve's radius.
ALONG_RADIUS_FRACTION = 0.5

#: Fewer band vertices than this and the terms beyond the quadratic are dropped.
_FULL_MIN = 12

#: Fewer band vertices than this and the quadratic terms are dropped (plane fit).
_QUADRATIC_MIN = 7

#: The fit's rows are solved for the weighted band vertices only when the most any row
#: has is at most this fraction of the padded width: the solve's time is in proportion
#: to its right-hand sides, and near the full width the fewer do not pay for placing
#: the solution's columns back (measured on the paper's samples: 0.37-0.62 of the width
#: on the end-to-end guests, 0.95 on the patches).
_COMPACT_WIDTH = 0.75


@dataclass(frozen=True)
class BandFit:
    """A band fit along one curve.

    Attributes
    ----------
    weights : scipy.sparse.csr_matrix, shape (k, n)
        ``weights @ X`` is the fitted cross-curve derivative ``c`` (k, 3) at each
        curve vertex for any positions ``X`` (n, 3) of the same mesh (the local
        coordinates are those of the configuration fitted).
    frames : SeamFrames
        Of the configuration fitted: the fit's unit normal (sign of the face
        orientation), the curve tangent over the band, and the unit direction
        into the surface (``c`` without its component along the tangent).
    band : float
        Band width in mesh units.
    counts : ndarray of int64, shape (k,)
        Band vertices used at each curve vertex.
    slope_error : ndarray, shape (k,)
        Standard error of the fitted slope off the curve (radians for small
        angles), from the residuals of the fit: how finely the band can
        resolve a crease there (0 where the band has too few vertices to say).
    """

    weights: sp.csr_matrix
    frames: SeamFrames
    band: float
    counts: np.ndarray
    slope_error: np.ndarray


def curve_tangents(P: np.ndarray, closed: bool, span: float) -> np.ndarray:
    """Unit tangents of a polyline, each the chord over an arc length ``span`` centred on it.

    Parameters
    ----------
    P : ndarray, shape (k, 3)
    closed : bool
    span : float
        Arc length of the chord; capped at half a closed curve's length.

    Returns
    -------
    ndarray, shape (k, 3)
    """
    P = np.asarray(P, dtype=np.float64)
    k = len(P)
    si, length = arc_lengths(P, closed)
    if length <= 0:
        return np.zeros((k, 3))
    half = 0.5 * min(float(span), 0.5 * length if closed else length)
    if closed:
        # unroll one period each side so that the chord may cross the start
        S = np.concatenate([si - length, si, si + length, [2 * length]])
        R = np.vstack([P, P, P, P[:1]])
        lo, hi = si - half, si + half
    else:
        S, R = si, P
        lo, hi = np.maximum(si - half, 0.0), np.minimum(si + half, length)

    def at(t):
        return np.stack([np.interp(t, S, R[:, j]) for j in range(3)], axis=1)

    return unit(at(hi) - at(lo))


def along_curve_reach(
    P: np.ndarray, closed: bool, normals: np.ndarray | None = None, span: float | None = None
) -> float:
    """Half-width of a band fit along its curve: where the surface bends round the curve.

    A surface that turns about the curve's own direction (a tube round its end)
    cannot be followed by a quadratic fit over more than about half its radius
    of bending along the curve. That radius is read from the surface normals at
    the curve: the median angle they turn through per unit of arc length over
    ``span``; the reach is :data:`ALONG_RADIUS_FRACTION` of its inverse. Without
    normals, a closed curve's own radius (length / 2π) stands for it.

    Parameters
    ----------
    P : ndarray, shape (k, 3)
    closed : bool
    normals : ndarray, shape (k, 3), optional
        Unit surface normals at the curve points.
    span : float, optional
        Arc length over which the normals' turning is read (default: a tenth of
        the curve's length).

    Returns
    -------
    float
        ``inf`` where the surface does not bend along the curve (or an open
        curve without normals).
    """
    k = len(P)
    if k < 3:
        return float("inf")
    s, length = arc_lengths(P, closed)
    if normals is None:
        return ALONG_RADIUS_FRACTION * length / (2.0 * np.pi) if closed else float("inf")
    span = 0.1 * length if span is None else float(span)
    ahead = s + span
    if closed:
        j = np.searchsorted(s, ahead % length) % k
        arc = np.where(ahead < length, s[j] - s, s[j] + length - s)
    else:
        j = np.minimum(np.searchsorted(s, ahead), k - 1)
        arc = s[j] - s
    ok = arc > 0
    if not ok.any():
        return float("inf")
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", normals[ok], normals[j[ok]]), -1.0, 1.0))
    rate = float(np.median(turn / arc[ok]))
    return ALONG_RADIUS_FRACTION / rate if rate > 0 else float("inf")


def median_edge_near(V: np.ndarray, F: np.ndarray, curve: np.ndarray, rings: int = 2) -> float:
    """Median length of the edges of the faces within ``rings`` rings of a curve.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
    curve : ndarray of int64, shape (k,)
    rings : int

    Returns
    -------
    float
        0 for a mesh without faces near the curve.
    """
    F = np.asarray(F, dtype=np.int64)
    mark = np.zeros(len(V), dtype=bool)
    mark[np.asarray(curve, dtype=np.int64)] = True
    band = mark[F].any(axis=1)
    for _ in range(rings - 1):
        mark[F[band].reshape(-1)] = True
        band = mark[F].any(axis=1)
    G = F[band]
    if not len(G):
        return 0.0
    L = np.linalg.norm(V[G] - V[np.roll(G, -1, axis=1)], axis=2)
    return float(np.median(L))


def _orientation_side(F: np.ndarray, curve: np.ndarray, closed: bool) -> np.ndarray:
    """+1 where the curve runs along its faces' half-edges, −1 against them, 0 unknown.

    Per curve vertex, from the mesh edge to the next curve vertex (the previous
    one at the end of an open curve); a vertex without such an edge takes the
    curve's majority, and 0 where no curve edge is a mesh edge at all.
    """
    k = len(curve)
    side = np.zeros(k)
    if k < 2 or not len(F):
        return side
    n = int(max(F.max(), curve.max())) + 1
    on = np.zeros(n, dtype=bool)
    on[curve] = True
    F = F[on[F].sum(axis=1) >= 2]  # only faces with a curve edge can hold one
    start = F.reshape(-1)
    end = F[:, [1, 2, 0]].reshape(-1)
    forward = set((start * n + end).tolist())
    nxt = np.roll(np.arange(k), -1)
    if not closed:
        nxt[-1] = k - 2
    a, b = curve, curve[nxt]
    along = np.fromiter(((x * n + y) in forward for x, y in zip(a, b)), dtype=bool, count=k)
    against = np.fromiter(((y * n + x) in forward for x, y in zip(a, b)), dtype=bool, count=k)
    if not closed:
        along[-1], against[-1] = against[-1], along[-1]  # the last edge is walked backwards
    side[along & ~against] = 1.0
    side[against & ~along] = -1.0
    if (side == 0).any() and (side != 0).any():
        side[side == 0] = 1.0 if (side > 0).sum() >= (side < 0).sum() else -1.0
    return side


def _near_vertices(V: np.ndarray, F: np.ndarray, curve: np.ndarray, limit: float) -> np.ndarray:
    """Vertices within edge-path distance ``limit`` of the curve (the curve included)."""
    from scipy.sparse.csgraph import dijkstra

    n = len(V)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    # a zero-length edge would vanish from the sparse graph; keep it connected
    w = np.maximum(w, 1e-300)
    G = sp.csr_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n))
    d = dijkstra(G, directed=False, indices=np.unique(curve), min_only=True, limit=limit)
    return np.flatnonzero(np.isfinite(d))


def band_fit(
    V: np.ndarray,
    F: np.ndarray,
    curve: np.ndarray,
    closed: bool,
    band: float,
    *,
    curve_points: np.ndarray | None = None,
) -> BandFit:
    """Fit the surface beside a boundary curve over a band, at each curve vertex.

    The curve vertices are fitted in chunks of :func:`_rows_per_chunk` rows, so
    the work arrays (curve vertices × band vertices) stay within
    :data:`FIT_CHUNK_ENTRIES` entries whatever the band and the mesh; only the
    fit's rows grow with them, and those are refused beyond
    :data:`MAX_FIT_ENTRIES` before any is made. Each row's floats are those of
    one pass over the whole curve (the same operations on the same band
    vertices, padded to the same width).

    Parameters
    ----------
    V, F, curve, closed
        The mesh and its boundary curve, as in :func:`igljoin.frames.seam_frames`;
        the curve vertices are the fits' anchors.
    band : float
        Band width (> 0), in mesh units: the vertices within this distance of a
        curve vertex (and on the same sheet of the surface) enter its fit.
    curve_points : ndarray, shape (k, 3), optional
        Positions that give the curve tangents (default ``V[curve]``), e.g. the
        host curve when fitting a guest that lies on it.

    Returns
    -------
    BandFit

    Raises
    ------
    OptionsError
        When the fit's rows would hold more than :data:`MAX_FIT_ENTRIES`
        entries, with a ``smooth_band`` that fits.
    """
    # the compiled loops read V read-only and a curve of their own whatever the caller's
    # flags, so that a process loads one compiled version of each (a few ms apiece)
    V = np.ascontiguousarray(V, dtype=np.float64).view()
    V.flags.writeable = False
    F = np.asarray(F, dtype=np.int64)
    curve = np.array(curve, dtype=np.int64)
    band = float(band)
    n, k = len(V), len(curve)
    A = V[curve]
    P = A if curve_points is None else np.asarray(curve_points, dtype=np.float64)
    T = curve_tangents(P, closed, band)
    # only faces near the curve can enter a fit (a large host costs little)
    reach = 2.0 * band
    box = ((V >= A.min(axis=0) - reach) & (V <= A.max(axis=0) + reach)).all(axis=1)
    F = F[box[F].all(axis=1)]
    normals, areas = face_normals_areas(V, F)
    VN = unit(vertex_face_matrix(F, n) @ (normals * areas[:, None]))
    near = _near_vertices(V, F, curve, reach)
    from scipy.spatial import cKDTree  # here: scipy.spatial costs start-up time

    tree = cKDTree(V[near])
    # a short curve is queried once, its lists counted; a longer one is counted first and
    # queried a chunk at a time (WHOLE_QUERY_ENTRIES)
    whole = k * len(near) <= WHOLE_QUERY_ENTRIES
    if whole:
        found = tree.query_ball_point(A, band, return_sorted=False)
        counts = np.fromiter(map(len, found), dtype=np.int64, count=k)
    else:
        counts = np.asarray(tree.query_ball_point(A, band, return_length=True), dtype=np.int64)
    total = int(counts.sum())
    widest = int(counts.max()) if k else 0
    _check_size(band, k, total, widest)
    M = max(widest, 1)
    rows = _rows_per_chunk(M)
    chunks = [slice(s, min(s + rows, k)) for s in range(0, k, rows)]
    offsets = np.concatenate([[0], np.cumsum(counts)])
    # every row's band vertices, one after another (what its rows will hold, at most)
    hits = np.empty(total, dtype=np.int32 if n < 2**31 else np.int64)
    n0 = VN[curve]
    pulled = np.zeros((k, 3))
    # which band vertices are on the curve vertex's sheet, kept for pass 2 (packed bits,
    # k × M / 8 bytes, when there are several chunks); pass 2 places each chunk's band
    # vertices again from ``hits``, so that only one chunk's rows are held at a time
    sheets = []
    for sl in chunks:
        lists = found[sl] if whole else tree.query_ball_point(A[sl], band, return_sorted=False)
        size = int(offsets[sl.stop] - offsets[sl.start])
        got = np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=size)
        hits[offsets[sl.start] : offsets[sl.stop]] = near[_sorted_in_rows(got, counts[sl])]
        valid, pulled[sl] = _band_rows(hits, offsets, counts, curve, VN, sl.start, sl.stop, M)
        sheets.append(valid if len(chunks) == 1 else np.packbits(valid, axis=1))
        del valid
    found = None  # the whole curve's lists, no longer needed
    n0 = unit(pulled + n0)
    del pulled
    g0 = unit(np.cross(n0, T))
    # into the surface: the faces lie to the left of their own boundary edges (seen
    # along the normal), so the curve's order against theirs fixes the side exactly;
    # where no curve edge is a mesh edge, the band's centroid decides (in the chunks)
    side = _orientation_side(F, curve, closed)
    along = min(band, along_curve_reach(P, closed, n0, band))
    parts, used, normal, inward, slope_error = [], [], [], [], []
    for i, sl in enumerate(chunks):
        idx = _padded_rows(hits, offsets, counts, sl, M)
        valid = sheets[i] if len(chunks) == 1 else np.unpackbits(sheets[i], axis=1, count=M)
        valid = valid.view(bool)
        sheets[i] = None
        g = g0[sl]
        unknown = side[sl] == 0
        if unknown.any():
            w_area = np.where(valid, 1.0, 0.0)
            D = V[idx] - A[sl, None, :]
            side[sl][unknown] = np.sign(np.einsum("km,kmj,kj->k", w_area, D, g))[unknown]
            del D
        g[side[sl] < 0] *= -1.0
        fit = _chunk_fit(V, idx, valid, A[sl], curve[sl], T[sl], g, n0[sl], band, along)
        parts.append(fit[0])
        used.append(fit[1])
        inward.append(fit[2])
        normal.append(fit[3])
        slope_error.append(fit[4])
    return BandFit(
        weights=sp.vstack(parts, format="csr") if parts else sp.csr_matrix((0, n)),
        frames=SeamFrames(
            normal=_rows_of(normal, (0, 3)),
            tangent=T,
            inward=_rows_of(inward, (0, 3)),
        ),
        band=band,
        counts=_rows_of(used, (0,), np.int64),
        slope_error=_rows_of(slope_error, (0,)),
    )


def _check_size(band: float, k: int, total: int, widest: int) -> None:
    """Refuse a fit whose rows would hold more than :data:`MAX_FIT_ENTRIES` entries.

    ``total`` band vertices summed over the ``k`` curve vertices (at most
    ``widest`` at one), counted before any array of the fit is made.
    """
    if total <= MAX_FIT_ENTRIES:
        return
    # the vertices within a band grow with its width² on a surface; 0.9 leaves room for
    # the unevenness of a real mesh
    narrower = band * 0.9 * (MAX_FIT_ENTRIES / total) ** 0.5
    raise OptionsError(
        f"a band fit {band:.3g} mesh units wide has {total:,} entries (up to {widest:,} mesh "
        f"vertices around each of {k:,} curve vertices; about "
        f"{_BYTES_PER_ENTRY * total / 1e9:.2g} GB for the join's copies and factor of its "
        f"rows), more than the size guard of {MAX_FIT_ENTRIES:,}: the mesh is much finer "
        f"than the band; give smooth_band={narrower:.3g} or less, or raise "
        "igljoin.bandfit.MAX_FIT_ENTRIES"
    )


def _sorted_in_rows(got: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``got`` (total,), rows of ``counts`` (r,) entries one after another, each row sorted.

    The tree's lists of the band vertices, in the order its sorted query gives them
    (one sort of row-major keys instead of one per list).
    """
    if not got.size:
        return got
    row = np.repeat(np.arange(counts.size, dtype=np.int64), counts)
    width = int(got.max()) + 1
    key = row * width + got
    key.sort()
    return key - row * width


def _rows_per_chunk(M: int) -> int:
    """Curve vertices fitted together when each has ``M`` band vertices (padded)."""
    return max(1, FIT_CHUNK_ENTRIES // M)


@nb.njit(cache=True)
def _band_rows(hits, offsets, counts, curve, VN, start: int, stop: int, M: int):
    """Which band vertices of curve vertices ``start:stop`` are on their sheet; their normals' sum.

    Returns ``valid`` (r, M) bool: row ``i``'s band vertices
    (``hits[offsets[i]:offsets[i + 1]]``, then padding) that are not the curve vertex and
    whose vertex normal (``VN``, (n, 3)) is on the curve vertex's sheet of the surface;
    and ``pulled`` (r, 3): the sum of those normals. Compiled, without the (r, M, 3)
    normals it gathered before: the floats of ``np.einsum("kmj,kj->km", VN[idx], n0)``
    (whose two-lane vector loop adds three products as the first and third, then the
    second; tests/test_band_fit_chunks.py compares the two) and of
    ``np.einsum("km,kmj->kj", valid, VN[idx])`` (first to last).
    """
    r = stop - start
    valid = np.zeros((r, M), dtype=np.bool_)
    pulled = np.zeros((r, 3))
    for i in range(r):
        q = curve[start + i]
        a0, a1, a2 = VN[q, 0], VN[q, 1], VN[q, 2]
        s0 = s1 = s2 = 0.0
        o = offsets[start + i]
        for m in range(counts[start + i]):
            h = hits[o + m]
            if h == q:
                continue
            b0, b1, b2 = VN[h, 0], VN[h, 1], VN[h, 2]
            if 0.0 + ((b0 * a0 + b2 * a2) + b1 * a1) > _SAME_SHEET_COS:
                valid[i, m] = True
                s0 += b0
                s1 += b1
                s2 += b2
        pulled[i, 0], pulled[i, 1], pulled[i, 2] = s0, s1, s2
    return valid, pulled


def _padded_rows(hits, offsets, counts, sl: slice, M: int) -> np.ndarray:
    """Band vertices of the curve vertices ``sl``, shape (r, M) int64: each row's band
    vertices (``hits[offsets[i]:offsets[i + 1]]``), then zeros."""
    idx = np.zeros((sl.stop - sl.start, M), dtype=np.int64)
    idx[np.arange(M)[None, :] < counts[sl, None]] = hits[offsets[sl.start] : offsets[sl.stop]]
    return idx


def _chunk_fit(V, idx, valid, A, curve, T, g0, n0, band: float, along: float):
    """The fit at ``r`` curve vertices from their padded band vertices.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    idx : ndarray of int64, shape (r, M)
        From :func:`_padded_rows`.
    valid : ndarray of bool, shape (r, M)
        From :func:`_band_rows`.
    A : ndarray, shape (r, 3)
        The curve vertices' positions.
    curve : ndarray of int64, shape (r,)
    T, g0, n0 : ndarray, shape (r, 3)
        Tangent, rough direction into the surface and band normal.
    band, along : float
        Band width across and along the curve.

    Returns
    -------
    rows : scipy.sparse.csr_matrix, shape (r, n)
    used : ndarray of int64, shape (r,)
    inward, normal : ndarray, shape (r, 3)
    slope_error : ndarray, shape (r,)
    """
    r = len(idx)
    # an ellipsoid: ``along`` wide in the curve's direction, ``band`` across it and
    # off the surface, so the bend of a tube around its end stays out of the fit
    X, w, _, used = _ellipsoid(V, idx, valid, A, T, g0, n0, band, band / along)
    Z = _fit_rows(X, w)
    beta = Z[:, 1, :] / band
    W = sp.csr_matrix(_weight_rows(beta, idx, curve, -beta.sum(axis=1)), shape=(r, len(V)))
    c = W @ V
    inward = unit(c - np.einsum("ij,ij->i", c, T)[:, None] * T)
    # where the band is empty keep the rough frame
    empty = used == 0
    inward[empty] = g0[empty]
    normal = unit(np.cross(inward, T))
    normal[np.einsum("ij,ij->i", normal, n0) < 0] *= -1.0
    z, present = _slope_inputs(V, idx, A, normal, Z)
    return W, used, inward, normal, _slope_error(Z, X, z, present, band, used)


def _rows_of(chunks: list, empty_shape: tuple, dtype=np.float64) -> np.ndarray:
    """The chunks' arrays stacked along their first axis (an empty one of no chunks)."""
    return np.concatenate(chunks) if chunks else np.zeros(empty_shape, dtype=dtype)


def _slope_error(Z, X, z, present, band: float, used: np.ndarray) -> np.ndarray:
    """Standard error of the fitted slope off the curve, from the fit's own residuals.

    The heights ``z_j`` of the band vertices over the fitted tangent plane are
    fitted by the same least squares; their residual variance ``σ²`` (per
    degree of freedom) and the fit's row ``Z_v`` give ``se = σ ‖Z_v‖ / band``
    (unit-free: radians for small angles). Noise of a scan, or a surface the
    quadratic does not follow, raises it; a clean smooth surface has ``se ≈ 0``.
    ``z`` (k, M) and ``present`` (k, M) from :func:`_slope_inputs`.
    """
    coef = np.einsum("kim,km->ki", Z, z)
    fitted = np.einsum("kmi,ki->km", X, coef)
    r = np.where(present, z - fitted, 0.0)
    dof = used - _parameters(used)
    sigma2 = (r * r).sum(axis=1) / np.maximum(dof, 1)
    se = np.sqrt(sigma2 * (Z[:, 1, :] ** 2).sum(axis=1)) / band
    return np.where(dof > 0, se, 0.0)


def _fit_rows(X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rows ``Z`` (k, 8, M) of the weighted least-squares fit by the columns ``X`` (k, M, 8).

    ``X`` from :func:`_columns`, weights ``w`` (k, M). ``Z[:, i] @ y`` is
    coefficient ``i`` of the fit of values ``y`` (k, M) at the band vertices;
    row 1 gives the ``v`` derivative at the curve vertex. A dropped (zero)
    column has a zero row.
    """
    # a band vertex of weight 0 (outside the ellipsoid, another sheet, the padding) has
    # a zero column in XᵀW and a zero column in Z: where they are many, only the others
    # are solved for, each row's in their order, the rows padded to the widest with zero
    # columns (at least two right-hand sides, as the full width has; one would take
    # LAPACK's other path)
    k, M = w.shape
    width = max(2, int((w > 0.0).sum(axis=1).max()) if k else 0)
    if width > _COMPACT_WIDTH * M:
        XtW, H = _normal_equations(X, w)
        return np.linalg.solve(_ridged(H), XtW)
    XtW, H, where = _weighted_normal_equations(X, w, width)
    return _scatter_columns(np.linalg.solve(_ridged(H), XtW), where, M)


def _ridged(H: np.ndarray) -> np.ndarray:
    """``H`` (k, p, p) with a small ridge, which keeps a thin or empty band solvable."""
    ridge = 1e-8 * np.maximum(np.trace(H, axis1=1, axis2=2), 1e-12)[:, None, None]
    return H + ridge * np.eye(H.shape[1])


@nb.njit(cache=True)
def _columns(u: np.ndarray, v: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Design columns (k, M, 8) of the fit, fewer where a band has few vertices.

    ``[u, v, u², uv, v², u³, u⁴, u²v]``: a quadratic, and how the surface bends
    along the curve beyond it (round a tube). Bands with fewer than
    :data:`_FULL_MIN` vertices drop the last three, with fewer than
    :data:`_QUADRATIC_MIN` the quadratic too (a plane: biased on a curved surface,
    so the last resort); dropped columns are zero. Compiled (one pass; each
    entry the one product the array expression ``u * u``, ``u * v``, ...
    rounds).
    """
    k, M = u.shape
    X = np.empty((k, M, 8))
    for r in range(k):
        full, quadratic = used[r] >= _FULL_MIN, used[r] >= _QUADRATIC_MIN
        for m in range(M):
            a, b = u[r, m], v[r, m]
            aa = a * a
            X[r, m, 0] = a
            X[r, m, 1] = b
            X[r, m, 2] = aa if quadratic else 0.0
            X[r, m, 3] = a * b if quadratic else 0.0
            X[r, m, 4] = b * b if quadratic else 0.0
            X[r, m, 5] = aa * a if full else 0.0
            X[r, m, 6] = aa * aa if full else 0.0
            X[r, m, 7] = aa * b if full else 0.0
    return X


def _parameters(used: np.ndarray) -> np.ndarray:
    """Number of fitted columns at each curve vertex (see :func:`_columns`)."""
    return np.where(used >= _FULL_MIN, 8, np.where(used >= _QUADRATIC_MIN, 5, 2))


@nb.njit(cache=True)
def _normal_equations(X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``XᵀW`` (k, p, M) and ``XᵀWX`` (k, p, p) of columns ``X`` (k, M, p) and weights ``w`` (k, M).

    Compiled: the products and the sums over the band vertices in the order
    of ``np.einsum("kmi,km->kim")`` and ``np.einsum("kim,kmj->kij")`` (each
    sum taken first to last), so the floats are theirs, without the einsum
    passes over (k, M, p) arrays; a band vertex of weight 0 (the padding of
    the shorter bands) adds only zeros and is skipped.
    """
    k, M, p = X.shape
    XtW = np.empty((k, p, M))
    H = np.zeros((k, p, p))
    for r in range(k):
        for m in range(M):
            wm = w[r, m]
            for i in range(p):
                XtW[r, i, m] = X[r, m, i] * wm
            if wm == 0.0:
                continue  # its products are zeros: adding them leaves every sum as it is
            for i in range(p):
                a = XtW[r, i, m]
                for j in range(p):
                    H[r, i, j] += a * X[r, m, j]
    return XtW, H


@nb.njit(cache=True)
def _weighted_normal_equations(X: np.ndarray, w: np.ndarray, width: int):
    """:func:`_normal_equations` with ``XᵀW``'s columns of weight 0 left out.

    Returns ``XᵀW`` (k, p, width): each row's columns of positive weight in their
    order, then zero columns; ``XᵀWX`` (k, p, p), the floats of
    :func:`_normal_equations`; and where each column came from (k, width), -1
    for the zero columns. ``width`` is at least the most columns of positive
    weight in a row.
    """
    k, M, p = X.shape
    XtW = np.zeros((k, p, width))
    H = np.zeros((k, p, p))
    where = np.full((k, width), -1, dtype=np.int64)
    for r in range(k):
        c = 0
        for m in range(M):
            wm = w[r, m]
            if wm == 0.0:
                continue
            where[r, c] = m
            for i in range(p):
                XtW[r, i, c] = X[r, m, i] * wm
            for i in range(p):
                a = XtW[r, i, c]
                for j in range(p):
                    H[r, i, j] += a * X[r, m, j]
            c += 1
    return XtW, H, where


@nb.njit(cache=True)
def _scatter_columns(Zc: np.ndarray, where: np.ndarray, M: int) -> np.ndarray:
    """``Z`` (k, p, M), zero but for the columns ``Zc`` (k, p, width) placed at ``where``."""
    k, p, width = Zc.shape
    Z = np.zeros((k, p, M))
    for r in range(k):
        for c in range(width):
            m = where[r, c]
            if m < 0:
                continue
            for i in range(p):
                Z[r, i, m] = Zc[r, i, c]
    return Z


@nb.njit(cache=True)
def _weight_rows(beta: np.ndarray, idx: np.ndarray, curve: np.ndarray, at_curve: np.ndarray):
    """The fit's rows as CSR arrays ``(data, indices, indptr)``, each row's columns sorted.

    Row ``i`` holds ``beta[i, m]`` (r, M) at column ``idx[i, m]`` (ascending along the
    row wherever ``beta`` is not 0: the band vertices in their sorted order) and
    ``at_curve[i]`` (r,) at ``curve[i]`` (r,), none of them 0 (a NaN is kept): the
    canonical matrix scipy makes of the same entries as coordinates (sorted, and no
    column twice, since a curve vertex has no weight in its own band), without its sort.
    """
    r, M = beta.shape
    indptr = np.zeros(r + 1, dtype=np.int64)
    for i in range(r):
        c = 0 if at_curve[i] == 0.0 else 1
        for m in range(M):
            if beta[i, m] != 0.0:
                c += 1
        indptr[i + 1] = indptr[i] + c
    indices = np.empty(indptr[r], dtype=np.int64)
    data = np.empty(indptr[r])
    for i in range(r):
        p, q, placed = indptr[i], curve[i], at_curve[i] == 0.0
        for m in range(M):
            b = beta[i, m]
            if b == 0.0:
                continue
            if not placed and q < idx[i, m]:
                indices[p], data[p] = q, at_curve[i]
                p += 1
                placed = True
            indices[p], data[p] = idx[i, m], b
            p += 1
        if not placed:
            indices[p], data[p] = q, at_curve[i]
    return data, indices, indptr


@nb.njit(cache=True)
def _nonzero_columns(Z: np.ndarray) -> np.ndarray:
    """Where a column of ``Z`` (k, p, M) holds a non-zero and no NaN, shape (k, M).

    ``np.abs(Z).sum(axis=1) > 0`` without its two (k, p, M) and (k, M) temporaries (a
    sum of magnitudes is positive exactly where one is, in any order, and NaN where one
    is NaN).
    """
    k, p, M = Z.shape
    out = np.empty((k, M), dtype=np.bool_)
    s = np.empty(M)
    for r in range(k):
        s[:] = 0.0
        for i in range(p):
            for m in range(M):
                s[m] += abs(Z[r, i, m])
        for m in range(M):
            out[r, m] = s[m] > 0.0
    return out


@nb.njit(cache=True)
def _ellipsoid(V, idx, valid, A, T, g0, n0, band: float, stretch: float):
    """Design columns and weights of the band vertices ``idx`` (r, M) of curve points ``A``.

    With ``D = V[idx] - A[:, None]``: ``u = D·T / band`` and ``v = D·g0 / band`` (r, M),
    the squared radius ``r2 = (u stretch)² + v² + (D·n0 / band)²`` of the ellipsoid,
    ``valid`` (r, M) narrowed to ``r2 <= 1`` (``inside``), the weights
    ``(1 - r2)² + 1e-3`` there (0 elsewhere), the vertices ``used`` (r,) inside, and
    the columns ``X = _columns(u, v, used)`` (r, M, 8). Returns ``X, w, inside, used``.
    Compiled, without the (r, M, 3) differences: the floats of the array expressions,
    each dot product as ``np.einsum("kmj,kj->km")`` adds its three products (the first
    and third, then the second).
    """
    r, M = idx.shape
    u = np.empty((r, M))
    v = np.empty((r, M))
    w = np.empty((r, M))
    inside = np.empty((r, M), dtype=np.bool_)
    used = np.zeros(r, dtype=np.int64)
    for i in range(r):
        t0, t1, t2 = T[i, 0], T[i, 1], T[i, 2]
        g_0, g_1, g_2 = g0[i, 0], g0[i, 1], g0[i, 2]
        n_0, n_1, n_2 = n0[i, 0], n0[i, 1], n0[i, 2]
        for m in range(M):
            h = idx[i, m]
            d0, d1, d2 = V[h, 0] - A[i, 0], V[h, 1] - A[i, 1], V[h, 2] - A[i, 2]
            a = (0.0 + ((d0 * t0 + d2 * t2) + d1 * t1)) / band
            b = (0.0 + ((d0 * g_0 + d2 * g_2) + d1 * g_1)) / band
            c = (0.0 + ((d0 * n_0 + d2 * n_2) + d1 * n_1)) / band
            a_s = a * stretch
            r2 = (a_s * a_s + b * b) + c * c
            ok = valid[i, m] and r2 <= 1.0
            u[i, m], v[i, m], inside[i, m] = a, b, ok
            w[i, m] = (1.0 - r2) * (1.0 - r2) + 1e-3 if ok else 0.0
            used[i] += ok
    return _columns(u, v, used), w, inside, used


@nb.njit(cache=True)
def _slope_inputs(V, idx, A, normal, Z):
    """:func:`_heights` and :func:`_nonzero_columns` in one compiled call (a process loads
    each compiled function it calls from Python once, a few milliseconds apiece)."""
    return _heights(V, idx, A, normal), _nonzero_columns(Z)


@nb.njit(cache=True)
def _heights(V, idx, A, normal):
    """Heights ``(V[idx] - A[:, None])·normal`` (r, M) of the band vertices ``idx`` (r, M)
    over the tangent planes at ``A`` (r, 3) of normal ``normal`` (r, 3): the floats of
    ``np.einsum("kmj,kj->km")`` (see :func:`_ellipsoid`), without the differences."""
    r, M = idx.shape
    z = np.empty((r, M))
    for i in range(r):
        n_0, n_1, n_2 = normal[i, 0], normal[i, 1], normal[i, 2]
        for m in range(M):
            h = idx[i, m]
            d0, d1, d2 = V[h, 0] - A[i, 0], V[h, 1] - A[i, 1], V[h, 2] - A[i, 2]
            z[i, m] = 0.0 + ((d0 * n_0 + d2 * n_2) + d1 * n_1)
    return z
