"""The band fit works through its curve in chunks: the same floats, bounded work arrays."""

from __future__ import annotations

import tracemalloc
from itertools import chain

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import bandfit, phantoms
from igljoin.frames import SeamFrames, face_normals_areas, unit, vertex_face_matrix

PAPER = [
    (sc, ln) for sc in ("end_to_end", "partial_patch") for ln in ("shorter", "equal", "longer")
]


def _whole_curve_fit(V, F, curve, closed, band, *, curve_points=None):
    """The band fit as one pass over the whole curve: (k, M) work arrays, no chunks.

    The code the chunked fit replaced (less its size guard), kept as the reference
    its floats are compared with: numpy's array expressions where the fit now has
    compiled loops (the sheet test, the ellipsoid, the heights, the rows' placing).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    curve = np.asarray(curve, dtype=np.int64)
    band = float(band)
    n, k = len(V), len(curve)
    A = V[curve]
    P = A if curve_points is None else np.asarray(curve_points, dtype=np.float64)
    T = bandfit.curve_tangents(P, closed, band)
    reach = 2.0 * band
    box = ((V >= A.min(axis=0) - reach) & (V <= A.max(axis=0) + reach)).all(axis=1)
    F = F[box[F].all(axis=1)]
    normals, areas = face_normals_areas(V, F)
    VN = unit(vertex_face_matrix(F, n) @ (normals * areas[:, None]))
    near = bandfit._near_vertices(V, F, curve, reach)
    from scipy.spatial import cKDTree

    tree = cKDTree(V[near])
    counts = np.asarray(tree.query_ball_point(A, band, return_length=True), dtype=np.int64)
    M = max(int(counts.max()) if k else 0, 1)
    hits = tree.query_ball_point(A, band)
    idx = np.zeros((k, M), dtype=np.int64)
    valid = np.arange(M)[None, :] < counts[:, None]
    total = int(counts.sum())
    if total:
        idx[valid] = near[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=total)]
    valid &= idx != curve[:, None]
    n0, VNb = VN[curve], VN[idx]
    valid &= np.einsum("kmj,kj->km", VNb, n0) > bandfit._SAME_SHEET_COS
    D = V[idx] - A[:, None, :]
    w_area = np.where(valid, 1.0, 0.0)
    n0 = unit(np.einsum("km,kmj->kj", w_area, VNb) + n0)
    g0 = unit(np.cross(n0, T))
    side = bandfit._orientation_side(F, curve, closed)
    unknown = side == 0
    if unknown.any():
        side[unknown] = np.sign(np.einsum("km,kmj,kj->k", w_area, D, g0))[unknown]
    g0[side < 0] *= -1.0
    along = min(band, bandfit.along_curve_reach(P, closed, n0, band))
    u = np.einsum("kmj,kj->km", D, T) / band
    v = np.einsum("kmj,kj->km", D, g0) / band
    ua = u * (band / along)
    r2 = ua * ua + v * v + (np.einsum("kmj,kj->km", D, n0) / band) ** 2
    valid &= r2 <= 1.0
    w = np.where(valid, (1.0 - r2) ** 2 + 1e-3, 0.0)
    used = valid.sum(axis=1)
    X = bandfit._columns(u, v, used)
    Z = _padded_fit_rows(X, w)
    beta = Z[:, 1, :] / band
    W = _coordinates_csr(beta, idx, curve, -beta.sum(axis=1), n)
    c = W @ V
    inward = unit(c - np.einsum("ij,ij->i", c, T)[:, None] * T)
    empty = ~valid.any(axis=1)
    inward[empty] = g0[empty]
    normal = unit(np.cross(inward, T))
    normal[np.einsum("ij,ij->i", normal, n0) < 0] *= -1.0
    return bandfit.BandFit(
        weights=W,
        frames=SeamFrames(normal=normal, tangent=T, inward=inward),
        band=band,
        counts=used,
        # the heights and the weighted columns' mark as the array expressions the compiled
        # loops replaced
        slope_error=bandfit._slope_error(
            Z, X, np.einsum("kmj,kj->km", D, normal), np.abs(Z).sum(axis=1) > 0, band, used
        ),
    )


def _padded_fit_rows(X, w):
    """The fit's rows solved over every band vertex, the padding's included (the solve the
    fit made before it left out the band vertices of weight 0)."""
    XtW, H = bandfit._normal_equations(X, w)
    return np.linalg.solve(bandfit._ridged(H), XtW)


def _assert_same(a, b):
    """Bit-for-bit equality of two arrays (same shape and dtype; NaN equals NaN; the sign
    of a zero counts)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    if a.dtype.kind == "f":
        assert np.array_equal(np.signbit(a)[~np.isnan(a)], np.signbit(b)[~np.isnan(b)])


def _assert_same_fit(a, b):
    _assert_same(a.counts, b.counts)
    _assert_same(a.slope_error, b.slope_error)
    for name in ("normal", "tangent", "inward"):
        _assert_same(getattr(a.frames, name), getattr(b.frames, name))
    assert a.band == b.band
    for name in ("data", "indices", "indptr"):
        _assert_same(getattr(a.weights, name), getattr(b.weights, name))
    assert a.weights.shape == b.weights.shape


@pytest.fixture(scope="module")
def fit_cases():
    """The band fits a default join makes (host, rest guest along the seam and at the host
    curve) on the paper samples, a finer tube guest, a fit along a host curve (the
    crease's), and one along a curve that follows no mesh edge (every other seam vertex:
    its side into the surface comes from the band, not from the faces' orientation)."""
    cases = []
    for key in PAPER:
        s = phantoms.paper_sample(*key)
        solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
        c, part = solver.corr, solver.parts[0]
        curve, band = solver.pairs[0].host_curve, solver.bands[0]
        cases.append((key, s.host.V, s.host.F, curve.indices, curve.closed, band, None))
        cases.append((key, c.V, c.F, part.seam, curve.closed, band, None))
        cases.append(
            (key, c.V, c.F, part.seam[part.host_hit], curve.closed, band, None),
        )
    s = phantoms.paper_sample("end_to_end", "equal", guest_resolution=2.0)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    c, part = solver.corr, solver.parts[0]
    curve, band = solver.pairs[0].host_curve, solver.bands[0]
    fine = ("tube, 4x finer guest",)
    cases.append((fine, c.V, c.F, part.seam, curve.closed, band, None))
    at = part.seam[part.host_hit]
    cases.append((fine, c.V, c.F, at, curve.closed, band, s.host.V[curve.indices]))
    cases.append((fine, c.V, c.F, part.seam[::2], curve.closed, band, None))
    return cases


@pytest.mark.parametrize("rows", [None, 1, 2, 7])
def test_the_chunked_fit_is_the_whole_curve_fit_to_the_bit(fit_cases, rows, monkeypatch):
    if rows is not None:
        monkeypatch.setattr(bandfit, "_rows_per_chunk", lambda M: rows)
    for _, V, F, curve, closed, band, points in fit_cases:
        a = bandfit.band_fit(V, F, curve, closed, band, curve_points=points)
        b = _whole_curve_fit(V, F, curve, closed, band, curve_points=points)
        _assert_same_fit(a, b)


def test_a_curve_counted_before_its_query_is_fitted_to_the_bit(fit_cases, monkeypatch):
    # a curve whose lists could exceed WHOLE_QUERY_ENTRIES is counted first and queried
    # a chunk at a time (a short one is queried once): budgets of 0 entries send every
    # curve that way, one row per chunk
    monkeypatch.setattr(bandfit, "FIT_CHUNK_ENTRIES", 0)
    monkeypatch.setattr(bandfit, "WHOLE_QUERY_ENTRIES", 0)
    for _, V, F, curve, closed, band, points in fit_cases:
        a = bandfit.band_fit(V, F, curve, closed, band, curve_points=points)
        b = _whole_curve_fit(V, F, curve, closed, band, curve_points=points)
        _assert_same_fit(a, b)


#: Real cuts from the corpus: four scans of different resolution, each kind of cut (a
#: ball, a plane along edges, a plane splitting triangles, which leaves slivers on the
#: seam), small and large pieces.
REAL = (
    ("bunny10k_textured.obj", "ball", 1),
    ("bunny10k_textured.obj", "split", 2),
    ("bunny.obj", "edges", 1),
    ("bunny.obj", "split", 1),
    ("cow.obj", "split", 0),
    ("cow.obj", "edges", 2),
    ("airplane.obj", "split", 2),
    ("bone.ply", "ball", 1),
)


@pytest.fixture(scope="module")
def real_fit_cases():
    """Band fits along real cuts: on the host and on the cut piece, three median edges wide."""
    pytest.importorskip("pymeshlab")  # ships the real meshes
    from .cuts import CORPUS, corpus_cut, read_sample

    cases = []
    for name, style, place in REAL:
        case = [c for c in CORPUS if c.mesh == name and c.style == style][place]
        cut = corpus_cut(case, read_sample(name))
        curve = np.asarray(cut.host_curve)
        edges = np.linalg.norm(cut.host.V[curve] - np.roll(cut.host.V[curve], 1, axis=0), axis=1)
        band = bandfit.BAND_EDGES * float(np.median(edges))
        cases.append((cut.host.V, cut.host.F, curve, band))
        cases.append((cut.piece.V, cut.piece.F, np.asarray(cut.piece_at_host), band))
    return cases


@pytest.mark.parametrize("rows", [None, 1, 7])
def test_the_chunked_fit_is_the_whole_curve_fit_on_real_cuts(real_fit_cases, rows, monkeypatch):
    if rows is not None:
        monkeypatch.setattr(bandfit, "_rows_per_chunk", lambda M: rows)
    for V, F, curve, band in real_fit_cases:
        a = bandfit.band_fit(V, F, curve, True, band)
        b = _whole_curve_fit(V, F, curve, True, band)
        _assert_same_fit(a, b)


def test_the_cases_cover_chunk_boundaries_and_the_unknown_side(fit_cases):
    # rows of 7 leave a last chunk shorter than the others on some curve (a boundary
    # inside the curve, not only at its end), and one curve has no edge of the mesh
    lengths = {len(case[3]) for case in fit_cases}
    assert any(k % 7 and k > 7 for k in lengths)
    _, V, F, curve, closed, *_ = fit_cases[-1]
    assert (bandfit._orientation_side(np.asarray(F), np.asarray(curve), closed) == 0).all()


def test_the_fit_is_refused_before_any_chunk(fit_cases, monkeypatch):
    _, V, F, curve, closed, band, _ = fit_cases[-3]
    fit = bandfit.band_fit(V, F, curve, closed, band)
    monkeypatch.setattr(bandfit, "MAX_FIT_ENTRIES", fit.weights.nnz // 2)

    def no_chunk(*args):
        raise AssertionError("a chunk of the fit was made")

    monkeypatch.setattr(bandfit, "_band_rows", no_chunk)
    with pytest.raises(igljoin.OptionsError, match="smooth_band=.*MAX_FIT_ENTRIES") as err:
        bandfit.band_fit(V, F, curve, closed, band)
    # the band it names fits: its entries are under the guard
    narrower = float(str(err.value).split("smooth_band=")[1].split(" ")[0])
    monkeypatch.undo()
    monkeypatch.setattr(bandfit, "MAX_FIT_ENTRIES", fit.weights.nnz // 2)
    assert bandfit.band_fit(V, F, curve, closed, narrower).weights.nnz <= fit.weights.nnz // 2


def _peak_bytes(call) -> int:
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_the_fits_memory_does_not_grow_with_curve_times_band(fit_cases, monkeypatch):
    _, V, F, curve, closed, band, _ = fit_cases[-3]
    k, M = len(curve), int(bandfit.band_fit(V, F, curve, closed, band).weights.nnz / len(curve))
    # chunks of a tenth of curve × mean band vertices: since the chunks are padded to the
    # widest row, they hold at most a tenth of the curve, and their work arrays at most a
    # tenth of the whole curve's
    monkeypatch.setattr(bandfit, "FIT_CHUNK_ENTRIES", k * M // 10)
    chunked = _peak_bytes(lambda: bandfit.band_fit(V, F, curve, closed, band))
    whole = _peak_bytes(lambda: _whole_curve_fit(V, F, curve, closed, band))
    # the whole curve's work arrays (a few hundred bytes per curve × band vertex, all
    # alive at once) dominate its peak; the chunked fit holds a tenth of them at a time,
    # plus what both share (the mesh's normals, the tree, the rows themselves). Measured
    # 31.2 MB against 2.3 MB (13.5x) on this 9,800-vertex guest (230 seam vertices);
    # 5x leaves room for allocator and library changes, while a fit whose work arrays
    # grew with the whole curve again would come out near 1x
    assert whole > 5 * chunked


@pytest.mark.parametrize("M, most", [(1, 0), (2, 1), (3, 2), (40, 20), (40, 39)])
def test_the_rows_solved_without_the_weightless_band_vertices_are_the_padded_rows(
    M, most, monkeypatch
):
    # rows with no, one and up to ``most`` band vertices weighted, anywhere in the row:
    # the fit solves for them only (two columns at least) — here whatever their share of
    # the row, so that every case but a single column takes that path — and each row of Z
    # must be the one the solve over all M columns gives, zeros elsewhere
    monkeypatch.setattr(bandfit, "_COMPACT_WIDTH", 1.0)
    compact = []
    weighted = bandfit._weighted_normal_equations
    monkeypatch.setattr(
        bandfit,
        "_weighted_normal_equations",
        lambda *a: compact.append(1) or weighted(*a),
    )
    rng = np.random.default_rng(M + most)
    k = 60
    u, v = rng.uniform(-1.0, 1.0, (2, k, M))
    present = np.zeros((k, M), dtype=bool)
    for r in range(k):
        present[r, rng.permutation(M)[: r % (most + 1)]] = True
    w = np.where(present, rng.uniform(1e-3, 1.0, (k, M)), 0.0)
    X = bandfit._columns(u, v, present.sum(axis=1))
    Z = bandfit._fit_rows(X, w)
    # equal as numbers: a weightless column's zeros may be -0.0 in the padded solve and
    # 0.0 in the placed rows (neither enters the fit's rows, which leave zeros out)
    padded = _padded_fit_rows(X, w)
    assert Z.shape == padded.shape and np.array_equal(Z, padded)
    assert (Z[np.broadcast_to(~present[:, None, :], Z.shape)] == 0).all()
    assert bool(compact) == (M >= 2)  # a single column is solved as it is


def _coordinates_csr(beta, idx, curve, at_curve, n):
    """The rows as scipy makes them from coordinates (what the fit did before it placed
    them itself)."""
    r, M = beta.shape
    data = np.concatenate([beta.reshape(-1), at_curve])
    cols = np.concatenate([idx.reshape(-1), curve])
    rows = np.concatenate([np.repeat(np.arange(r), M), np.arange(r)])
    keep = data != 0
    return sp.csr_matrix((data[keep], (rows[keep], cols[keep])), shape=(r, n))


def test_the_rows_placed_in_order_are_the_matrix_of_their_coordinates():
    # rows whose curve vertex's column comes first, last, between two band vertices, and
    # whose curve entry is 0; band weights of 0 and -0.0 (left out), NaN (kept), and a
    # row with no band weight at all
    rng = np.random.default_rng(3)
    r, M, n = 40, 12, 200
    idx = np.zeros((r, M), dtype=np.int64)
    beta = np.zeros((r, M))
    curve = rng.integers(0, n, r)
    for i in range(r):
        m = rng.integers(0, M + 1) if i else 0
        others = np.setdiff1d(np.arange(n), [curve[i]])
        idx[i, :m] = np.sort(rng.choice(others, m, replace=False))
        beta[i, :m] = rng.normal(size=m)
        beta[i, : m // 3] = 0.0
    beta[5, 1], beta[6, 2] = -0.0, np.nan
    curve[7], curve[8] = 0, n - 1  # before and after every band vertex
    at_curve = -np.nansum(beta, axis=1)
    at_curve[9] = 0.0
    a = sp.csr_matrix(bandfit._weight_rows(beta, idx, curve, at_curve), shape=(r, n))
    b = _coordinates_csr(beta, idx, curve, at_curve, n)
    for name in ("data", "indices", "indptr"):
        _assert_same(getattr(a, name), getattr(b, name))
    assert a.has_canonical_format


def test_the_marked_columns_are_those_of_a_positive_sum_of_magnitudes():
    rng = np.random.default_rng(4)
    Z = rng.normal(size=(6, 8, 30))
    Z[:, :, ::3] = 0.0
    Z[0, :, 1] = -0.0
    Z[1, 4, 2] = np.nan
    Z[2, 3, 4] = np.inf
    Z[3, :, 5] = 0.0
    Z[3, 7, 5] = 5e-324  # the smallest positive float
    _assert_same(bandfit._nonzero_columns(Z), np.abs(Z).sum(axis=1) > 0)


def test_the_compiled_local_coordinates_are_the_einsums():
    # rows of band vertices (with padding at vertex 0) spread from well inside the band
    # to mostly outside it, so that rows fit a plane, a quadratic and the full columns;
    # frames and a stretch along the curve as the fit has them. Every array equal to the
    # bit to the expressions the compiled loops replaced, the sign of a zero included.
    # The loops add a dot product's three terms in the order numpy's einsum does on this
    # numpy (first and third, then second): a numpy that sums otherwise fails this test
    # by rounding only, and the loops' order is then what to change
    rng = np.random.default_rng(5)
    r, M, band, along = 30, 50, 1.0, 0.7
    A = rng.normal(size=(r, 3))
    spread = np.linspace(0.2, 3.0, r)
    V = np.concatenate([(A[:, None, :] + spread[:, None, None] * rng.normal(size=(r, 40, 3)))
                        .reshape(-1, 3), A[:1]])  # fmt: skip
    idx = np.zeros((r, M), dtype=np.int64)
    idx[:, :40] = np.arange(r * 40).reshape(r, 40)
    idx[0, 0] = len(V) - 1  # a band vertex at its curve point: differences of 0
    T, g0, n0, normal = (unit(rng.normal(size=(r, 3))) for _ in range(4))
    # products 0 × negative are -0.0, their sum too; numpy's einsum adds it to a 0.0
    T[0], normal[0] = -np.abs(T[0]), -np.abs(normal[0])
    valid = (rng.random((r, M)) < 0.9) & (np.arange(M) < 40)
    X, w, inside, used = bandfit._ellipsoid(V, idx, valid, A, T, g0, n0, band, band / along)
    D = V[idx] - A[:, None, :]
    u = np.einsum("kmj,kj->km", D, T) / band
    v = np.einsum("kmj,kj->km", D, g0) / band
    ua = u * (band / along)
    r2 = ua * ua + v * v + (np.einsum("kmj,kj->km", D, n0) / band) ** 2
    inside0 = valid & (r2 <= 1.0)
    assert set(bandfit._parameters(inside0.sum(axis=1)).tolist()) == {2, 5, 8}
    _assert_same(inside, inside0)
    _assert_same(used, inside0.sum(axis=1))
    _assert_same(X, bandfit._columns(u, v, inside0.sum(axis=1)))
    _assert_same(w, np.where(inside0, (1.0 - r2) ** 2 + 1e-3, 0.0))
    Z = rng.normal(size=(r, 8, M))
    Z[:, :, ::4] = 0.0
    z, present = bandfit._slope_inputs(V, idx, A, normal, Z)
    _assert_same(z, np.einsum("kmj,kj->km", D, normal))
    _assert_same(present, np.abs(Z).sum(axis=1) > 0)
