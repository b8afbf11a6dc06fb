"""A two-level preconditioner: the factored ``P`` plus a coarse Gauss–Newton correction.

The quasi-Newton iteration of :mod:`igljoin.solve` starts every step from
``P⁻¹`` (``P = Σ c_t K_tᵀ W_t K_t``, one factorization, the same for the
three coordinates). ``P`` does not know that a neighbourhood may turn at
little cost — the shape term refits its rotation — so the soft bending and
turning modes take many iterations, more the finer the mesh. The
Gauss–Newton model with the rotations eliminated (:mod:`igljoin.newton`)
knows them but costs 10–17× ``P``'s factorization at full size.

This module keeps ``P`` on the fine mesh and resolves the model on a coarse
space only: the free vertices are grouped into connected clusters of about
``cluster_size`` vertices (:func:`clusters`), each with its six rigid
motions — three translations and three infinitesimal rotations about its
centroid at the current positions (:func:`rigid_prolongation`) — and three
bending motions (:func:`bending_prolongation`; ``A`` of shape (3 m, 9 a)).
The coarse matrix ``A_c = Aᵀ H A`` is the model ``H`` projected onto them,
computed from the model's factor rows on the terms' operators
(:func:`igljoin.newton.factor_rows`) without assembling ``H`` or forming
its factors, and
factored (9 a unknowns, a few thousand); both are rebuilt at the current
iterate when the guest has turned far from where they were built (the
values only: the patterns are the first build's; the coarse system is then
factored anew). The initial inverse Hessian of
the quasi-Newton steps becomes

* additive: ``P⁻¹ + A A_c⁻¹ Aᵀ``, or
* balancing (``balancing=True``): ``C + (I − C H) P⁻¹ (I − H C)`` with
  ``C = A A_c⁻¹ Aᵀ``, exact on the coarse space (two products with ``H``
  per step, in factored form).

Both are symmetric positive definite, so the quasi-Newton steps stay
descent directions and the line search keeps the energy from rising.
"""

from __future__ import annotations

import functools
import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from . import coarse_kernels as ck
from .errors import OptionsError, SolveError
from .linsolve import AugmentedQuadratic, FixedQuadratic, augmented_upper, available_backends
from .newton import (
    dofs,
    factor_entries,
    factor_rows,
    factors_product,
    gauss_newton_factors,
    rotation_pattern,
    row_directions,
)
from .terms import ShapeTerm, row_patterns

__all__ = [
    "clusters",
    "rigid_prolongation",
    "bending_prolongation",
    "TwoLevelModel",
    "preferred_model",
    "AUTO_FROM_VERTICES",
    "AUTO_MODEL",
    "MAX_MODEL_ENTRIES",
    "AUTO_MAX_MODEL_ENTRIES",
    "SPANNED_BENDING",
    "CONCURRENT_FROM_VERTICES",
]

# relative ridge added to the coarse matrix: a cluster of three nearly collinear vertices
# has a nearly free rotation about their line; 1e-10 of the mean diagonal keeps its
# factorization finite without changing any other coarse mode measurably
_RIDGE = 1e-10

#: The bending motions of a cluster of fewer than six vertices whose part outside its
#: rigid motions' span is at most this fraction of their size (the smallest eigenvalue of
#: the Schur complement of the rigid block in the cluster's Gram matrix over the bending
#: block's trace) are left out of the coarse space. A flat cluster of fewer than six
#: vertices has too few normal displacements for three bending motions beside the tilts:
#: on a 30k-vertex patch three clusters of three vertices have ratios of 6e-15 and less
#: (spanned to rounding) and their coarse system's pivots were perturbed (7), which made
#: "auto" give its model up. The smallest others measured, in models that factor soundly:
#: 7.8e-8 (30k patch, five vertices), 2.3e-7 (100k patch), 2.0e-5 (20k patch); larger
#: clusters along a tube's ring have one bending motion nearly rigid (1.9e-14 on the 20k
#: tube, ten vertices; 1.6e-13 on the 100k tube, twenty; 7.3e-11 on the 40k tube) and the
#: other two not: they keep all three, as before (leaving out only the spanned direction
#: was not tried).
SPANNED_BENDING = 1e-12

# fewer vertices than this leave a flat cluster's bending motions spanned (three rigid and
# three bending normal displacements)
_BENDING_VERTICES = 6

#: Free vertices from which the additive form's coarse solve runs on a second thread beside
#: the fine back-solve. Measured with the worker kept (quiet machine, medians of three to
#: five alternated solves, the same iterations): at the paper's size the explicit
#: "two-level" join took 1.11x (the longer patch, 120 against 108 ms) and 1.06x (e2e equal)
#: the time of the solves one after the other; the default join at 24k 0.89x (patch, 1.13
#: against 1.27 s) and 0.88x (tube, 8.4 against 9.5 s); the 100k patch's back-solves 0.7x.
CONCURRENT_FROM_VERTICES = 20_000

#: Largest number of entries the model may hold (:attr:`TwoLevelModel.model_entries`: the
#: coarse system, :attr:`TwoLevelModel.coarse_entries`, the operators' cluster patterns and
#: the free vertices' motions; the balancing form adds the Gauss–Newton model's factors,
#: :func:`igljoin.newton.factor_entries`), counted from the patterns before any of it is
#: built. Measured with Pardiso, the first build peaks 36-40 bytes per entry above the
#: solver's own memory, most of it the coarse factorization (100k patch: 11.0 M entries,
#: 0.39 GB; 300k tube: 34 M, 1.35 GB); the 1M tube counts 131 M, and its join went from
#: 7.8 GB after the set-up to 14.8 GB at the first build (at most 53 bytes per entry, with
#: copies of the coarse system since dropped). A rebuild lets the last factorization go
#: first and adds a fifth of that. 1.6e8 entries are about 8 GB. Past it
#: ``preconditioner="auto"`` keeps the factored ``P`` and ``"two-level"`` is refused.
MAX_MODEL_ENTRIES = 160_000_000

#: Largest count ``preconditioner="auto"`` builds (past it, it keeps the factored ``P``):
#: where the model pays was measured, not where it fits. The 300k tube (34 M entries)
#: converged in 485 iterations and 415 s against ``P``'s 1,316 and 523 s; the 1M tube
#: (131 M) rebuilt its coarse space 16 times at 22.5 s a factorization, 46 of its 88 local
#: steps rejected trials, and stood at 41 iterations after 600 s (``P``: 451) with a peak
#: of 19.5 GB against 10 GB. 6e7 entries (about 3 GB at a first build) lies between.
AUTO_MAX_MODEL_ENTRIES = 60_000_000

#: Bytes a first build spends per counted entry (the 36-53 measured above, rounded up).
_BYTES_PER_ENTRY = 50

# a term whose rows reach this many clusters on average (the smooth join's band rows:
# 82 at 100k guest vertices, 222 at 300k) is kept as rows of J A beside A_c's local part
# (an augmented system) instead of being assembled into A_c, where each row would
# couple all its clusters' pairs
_WIDE_CLUSTERS = 8


@functools.lru_cache(maxsize=1)
def _coarse_worker() -> ThreadPoolExecutor:
    """The one thread the additive coarse solves run on (:meth:`TwoLevelModel.solve_free`)."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="igljoin-coarse-solve")


# a forked child has none of its parent's threads: it starts its own worker
os.register_at_fork(after_in_child=_coarse_worker.cache_clear)


def _operator_clusters(term, labels: np.ndarray) -> tuple:
    """The clusters every row of ``term``'s operator ``K`` reaches, and its size.

    Found block by block on the patterns of the rows ``K`` stacks
    (:func:`igljoin.terms.row_patterns`) and put end to end
    (:func:`igljoin.coarse_kernels.row_clusters` reads each row alone, so they
    are the stack's): a rotation-aware shape term's stack ``[L; D; −D]`` is not
    made for the count (at 1M guest vertices 0.26 GB, which a model that
    falls back never reads).

    Parameters
    ----------
    term : Term
    labels : ndarray of int64, shape (n,)
        Every vertex's cluster, -1 at a fixed vertex.

    Returns
    -------
    of_K : tuple
        :func:`igljoin.coarse_kernels.row_clusters`'s ``(ptr, clusters, slot)`` of ``K``.
    rows, nnz : int
        ``K``'s rows and entries.
    """
    blocks = row_patterns(term)
    found: dict[int, tuple] = {}  # a pattern repeated (−D's is D's) is read once
    parts = []
    for M in blocks:
        if id(M) not in found:
            found[id(M)] = ck.row_clusters(M.indptr, M.indices, labels, 1)
        parts.append(found[id(M)])
    if len(parts) == 1:
        of_K = parts[0]
    else:
        ptr, start = [parts[0][0]], parts[0][0][-1]
        for p in parts[1:]:
            ptr.append(p[0][1:] + start)
            start += p[0][-1]
        of_K = (np.concatenate(ptr), *(np.concatenate([p[k] for p in parts]) for k in (1, 2)))
    return of_K, sum(M.shape[0] for M in blocks), sum(M.nnz for M in blocks)


class _CoarseAugmented(AugmentedQuadratic):
    """The augmented factorization of ``A_c = S + Uᵀ W U``, checked at ``A_c``'s accuracy.

    :class:`igljoin.linsolve.AugmentedQuadratic` without fixed rows, made
    from the build's own parts: ``S`` and ``U`` are kept as given (not
    copied into free blocks), ``Uᵀ`` is their transposed view, and Pardiso
    is handed the augmented matrix's upper triangle directly (not the whole
    matrix to cut it from) — at 300k guest vertices the copies and the
    assembled block matrix had cost half as much again as the factorization —
    in the form it reads (:func:`igljoin.linsolve.augmented_upper`: no
    conversion left to it).
    """

    #: the ridge of 1e-10 leaves ``A_c`` a condition number up to ~1e10, so a sound
    #: factorization may leave a probe residual up to ~1e10 × 2.2e-16 ≈ 2e-6 (measured
    #: 1.6e-8 on a 100k tube, as the assembled ``A_c``'s own factorization leaves); a
    #: singular system whose zero pivots were perturbed leaves one of order 1
    PROBE_RESIDUAL = 1e-4

    def __init__(self, S: sp.csr_matrix, U: sp.csr_matrix, weights: np.ndarray):
        n, weights = S.shape[0], np.asarray(weights, dtype=np.float64)
        keep = np.flatnonzero(weights > 0.0)
        Kf = U if len(keep) == U.shape[0] else sp.csr_matrix(U[keep])
        self._set_parts(
            n=n,
            fixed=np.zeros(0, dtype=np.int64),
            free=np.arange(n),
            Sff=S,
            Sfb=sp.csr_matrix((n, 0)),
            Kb=sp.csr_matrix((len(keep), 0)),
            Kft=Kf.T,
            cw=weights[keep],
        )
        if not n:
            return
        FixedQuadratic.made += 1
        # [[S, Uᵀ], [U, −W⁻¹]]'s upper triangle: S's, Uᵀ beside it, the diagonal below,
        # placed as Pardiso reads it (Uᵀ's rows made for it and let go)
        self._factor_augmented(augmented_upper(S, sp.csr_matrix(self.Kft), -1.0 / self.cw))

    def _refused(self, exc: Exception) -> str:
        """The message when Pardiso reports the error ``exc``: the coarse system's."""
        return f"{exc}; the coarse system could not be factored: use preconditioner='factored'"

    def _unsound(self, perturbed: int) -> str:
        """The message when the probe solve fails: the coarse system's."""
        return (
            f"the coarse system could not be factored ({perturbed} pivots of its augmented "
            "system were perturbed): use preconditioner='factored'"
        )


def clusters(X: np.ndarray, graph: sp.spmatrix, size: int) -> np.ndarray:
    """Connected clusters of about ``size`` vertices: graph Voronoi cells of grid seeds.

    The vertices are binned in a cubic grid whose cells hold about ``size``
    of them each; the vertex nearest each occupied cell's mean is a seed,
    and every vertex joins the seed nearest along the graph (edge lengths
    ``|x_i − x_j|``), so every cluster is connected.

    Parameters
    ----------
    X : ndarray, shape (m, 3)
        Positions.
    graph : sparse matrix, shape (m, m)
        Adjacency: any symmetric non-zero pattern (the diagonal is ignored).
    size : int
        Vertices per cluster aimed at.

    Returns
    -------
    ndarray of int64, shape (m,)
        Cluster of every vertex, 0 .. a − 1.
    """
    X = np.asarray(X, dtype=np.float64)
    m = len(X)
    size = max(int(size), 1)
    W = _edge_lengths(X, graph)
    lo = X.min(axis=0)
    h = (float(np.max(X.max(axis=0) - lo)) + 1e-300) / max(m / size, 1.0) ** (1.0 / 3.0)
    for _ in range(8):
        # a surface fills few cells of a volume grid: shrink the cell until they hold
        # about size vertices (the count per cell scales with the cell's area)
        cell = _grid_cells(np.floor((X - lo) / h).astype(np.int64))
        ratio = m / (int(cell.max()) + 1) / size
        if 0.7 < ratio < 1.4:
            break
        h /= ratio**0.5
    count = np.bincount(cell).astype(np.float64)
    mean = np.stack([np.bincount(cell, X[:, d]) for d in range(3)], 1) / count[:, None]
    offset = X - mean[cell]
    order = np.lexsort((np.einsum("ij,ij->i", offset, offset), cell))
    seeds = order[np.r_[True, cell[order][1:] != cell[order][:-1]]]
    # W is symmetric (a symmetric pattern, |x_i − x_j| = |x_j − x_i|): its directed
    # search is the undirected one, without the transpose scipy would add (half the time)
    _, _, source = csgraph.dijkstra(
        W, directed=True, indices=seeds, min_only=True, return_predecessors=True
    )
    lost = source < 0
    if lost.any():
        # parts of the graph no seed reaches: one cluster per connected part
        _, part = csgraph.connected_components(W[lost][:, lost], directed=False)
        source = source.copy()
        source[lost] = m + part
    _, labels = np.unique(source, return_inverse=True)
    return labels.astype(np.int64).ravel()


def _edge_lengths(X: np.ndarray, graph: sp.spmatrix) -> sp.csr_matrix:
    """``graph``'s pattern without its diagonal, each entry ``|x_i − x_j|``: shape (m, m).

    One compiled pass over a CSR ``graph``'s own index arrays
    (:func:`igljoin.coarse_kernels.edge_lengths`): at 10k guest vertices
    the conversion through COO and numpy's gathers had taken two thirds of
    the clusters' time.
    """
    G = graph if sp.isspmatrix_csr(graph) else sp.csr_matrix(graph)
    ptr, cols, length = ck.edge_lengths(G.indptr, G.indices, np.ascontiguousarray(X))
    return sp.csr_matrix((length, cols, ptr), shape=(len(X), len(X)))


def _grid_cells(keys: np.ndarray) -> np.ndarray:
    """The cell of every vertex (m,) from its grid coordinates (m, 3) ≥ 0, numbered as
    ``np.unique(keys, axis=0)`` numbers them (ascending x, then y, then z)."""
    span = keys.max(axis=0) + 1
    if float(np.prod(span.astype(np.float64))) < 2.0**62:
        # one integer per cell, ordered as its row: the same numbers for a tenth of the sort
        flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        _, cell = np.unique(flat, return_inverse=True)
    else:
        _, cell = np.unique(keys, axis=0, return_inverse=True)
    return cell.ravel()


def rigid_prolongation(X: np.ndarray, labels: np.ndarray) -> sp.csr_matrix:
    """The six rigid motions of every cluster, shape (3 m, 6 a), vertex-major rows.

    Columns ``6 j .. 6 j + 2`` translate cluster ``j``; ``6 j + 3 .. 6 j + 5``
    turn it infinitesimally about its centroid ``c_j`` (``θ × (x − c_j)``),
    divided by the cluster's radius so that all columns have the size of a
    unit translation.

    Parameters
    ----------
    X : ndarray, shape (m, 3)
    labels : ndarray of int64, shape (m,)
        Cluster of every vertex (:func:`clusters`).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3 m, 6 a)
    """
    a = int(labels.max()) + 1
    return _cluster_columns(_rigid_blocks(X, labels), labels, a)


def _rigid_blocks(X: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Every vertex's six rigid-motion rows (m, 3, 6) of :func:`rigid_prolongation`."""
    _, _, r, radius = _about_centroids(X, labels)
    r = r / np.maximum(radius[labels], 1e-300)[:, None]
    blocks = np.zeros((len(X), 3, 6))
    blocks[:, 0, 0] = blocks[:, 1, 1] = blocks[:, 2, 2] = 1.0
    # θ × r = −[r]× θ
    blocks[:, 0, 4], blocks[:, 0, 5] = r[:, 2], -r[:, 1]
    blocks[:, 1, 3], blocks[:, 1, 5] = -r[:, 2], r[:, 0]
    blocks[:, 2, 3], blocks[:, 2, 4] = r[:, 1], -r[:, 0]
    return blocks


def _about_centroids(X: np.ndarray, labels: np.ndarray):
    """Clusters ``a``, their sizes (a,), offsets from their centroids (m, 3), radii (a,)."""
    a = int(labels.max()) + 1
    count = np.bincount(labels, minlength=a).astype(np.float64)
    centre = np.stack([np.bincount(labels, X[:, d], minlength=a) for d in range(3)], 1)
    r = X - (centre / count[:, None])[labels]
    radius = np.sqrt(np.bincount(labels, np.einsum("ij,ij->i", r, r), minlength=a) / count)
    return a, count, r, radius


def _cluster_columns(blocks: np.ndarray, labels: np.ndarray, a: int) -> sp.csr_matrix:
    """Per-vertex blocks (m, 3, w) placed in their cluster's ``w`` columns: (3 m, w a)."""
    m, _, w = blocks.shape
    # one row per coordinate, its w entries in the cluster's columns (ascending)
    cols = np.broadcast_to(w * labels[:, None, None] + np.arange(w)[None, None, :], blocks.shape)
    indptr = np.arange(0, 3 * m * w + 1, w, dtype=np.int64)
    return sp.csr_matrix(
        (np.ascontiguousarray(blocks).ravel(), cols.ravel(), indptr), shape=(3 * m, w * a)
    )


def _motion_matrix(values, ptr, members, D: int, w: int, a: int) -> sp.csr_matrix:
    """The rows ``J A`` of :func:`igljoin.coarse_kernels.motion_rows_of`, shape (D r, w a).

    Row ``r D + d`` holds ``w`` entries per cluster of ``members[ptr[r]:ptr[r + 1]]``.
    """
    q = np.diff(ptr)
    indptr = np.r_[0, np.cumsum(np.repeat(w * q, D))].astype(np.int64)
    # the columns of every row of K (w per cluster), repeated for each of its D rows
    per_row = (w * members[:, None] + np.arange(w)[None, :]).ravel()
    start = np.repeat(w * ptr[:-1], D)
    cols = np.arange(indptr[-1]) - np.repeat(indptr[:-1] - start, np.diff(indptr))
    return sp.csr_matrix((values, per_row[cols], indptr), shape=(D * len(q), w * a))


def bending_prolongation(X: np.ndarray, labels: np.ndarray) -> sp.csr_matrix:
    """Three bending motions of every cluster, shape (3 m, 3 a): ``n u²``, ``n u v``, ``n v²``.

    ``n`` is the cluster's normal (the direction of least spread of its
    vertices), ``u``, ``v`` the coordinates along its two other principal
    directions divided by the cluster's radius; each quadratic has its
    cluster mean removed (that part is a translation, already among the
    rigid motions). With them a smooth bending of the surface — a tube's
    cross-section turning oval — is matched across the clusters' borders to
    third order instead of first: piecewise rigid motions represent it only
    at many times its energy (33× for the slowest error of the paper-sized
    tube), so the coarse correction barely moves it.

    Parameters
    ----------
    X : ndarray, shape (m, 3)
    labels : ndarray of int64, shape (m,)
        Cluster of every vertex (:func:`clusters`).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3 m, 3 a)
        Columns ``3 j .. 3 j + 2``: cluster ``j``'s ``n u²``, ``n u v``,
        ``n v²``; vertex-major rows.
    """
    a = int(labels.max()) + 1
    return _cluster_columns(_bending_blocks(X, labels), labels, a)


def _spanned_bending(blocks: np.ndarray, labels: np.ndarray, a: int) -> np.ndarray:
    """The clusters of fewer than six vertices whose bending motions their rigid ones span.

    Per such cluster, the Gram matrix ``G`` (9, 9) of its motions' columns
    (``blocks``, shape (m, 3, 9): six rigid, then three bending); the part
    of the bending columns outside the rigid span is the Schur complement
    ``G_bb − G_br G_rr⁻¹ G_rb`` (3, 3). A cluster is returned when its
    smallest eigenvalue is at most :data:`SPANNED_BENDING` times
    ``trace(G_bb)``. Only the few small clusters are looked at (a 100k
    patch has a handful), so a build spends next to nothing on it.

    Parameters
    ----------
    blocks : ndarray, shape (m, 3, 9)
    labels : ndarray of int64, shape (m,)
    a : int
        Number of clusters.

    Returns
    -------
    ndarray of int64, shape (k,)
        The clusters, ascending.
    """
    small = np.flatnonzero(np.bincount(labels, minlength=a) < _BENDING_VERTICES)
    if not small.size:
        return small.astype(np.int64)
    at = np.flatnonzero(np.isin(labels, small))
    which = np.searchsorted(small, labels[at])
    outer = np.einsum("vci,vcj->vij", blocks[at], blocks[at])
    G = np.zeros((len(small), 9, 9))
    np.add.at(G, which, outer)
    rigid, cross, bend = G[:, :6, :6], G[:, :6, 6:], G[:, 6:, 6:]
    # the rigid block is definite but for clusters of one or two vertices (turns about
    # their line move nothing, and their columns and cross terms are zero): a ridge far
    # below the test's threshold keeps the solve finite without changing its answer
    ridge = 1e-14 * np.trace(rigid, axis1=1, axis2=2) + 1e-300
    rigid = rigid + ridge[:, None, None] * np.eye(6)
    schur = bend - np.einsum("aij,aik->ajk", cross, np.linalg.solve(rigid, cross))
    smallest = np.linalg.eigvalsh(schur)[:, 0]
    size = np.trace(bend, axis1=1, axis2=2)
    return small[smallest <= SPANNED_BENDING * size].astype(np.int64)


def _bending_blocks(X: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Every vertex's three bending rows (m, 3, 3) of :func:`bending_prolongation`."""
    a, count, r, radius = _about_centroids(X, labels)
    outer = (r[:, :, None] * r[:, None, :]).reshape(-1, 9)
    cov = np.stack([np.bincount(labels, outer[:, k], minlength=a) for k in range(9)], 1)
    cov = cov.reshape(a, 3, 3)
    _, vec = np.linalg.eigh(cov)  # ascending: vec[:, :, 0] the normal
    r = r / np.maximum(radius[labels], 1e-300)[:, None]
    frame = vec[labels]
    u = np.einsum("ij,ij->i", r, frame[:, :, 2])
    v = np.einsum("ij,ij->i", r, frame[:, :, 1])
    normal = frame[:, :, 0]
    shapes = np.stack([u * u, u * v, v * v], 1)
    shapes -= (
        np.stack([np.bincount(labels, shapes[:, k], minlength=a) for k in range(3)], 1)
        / count[:, None]
    )[labels]
    return normal[:, :, None] * shapes[:, None, :]  # (m, 3, 3): coordinate, shape


class TwoLevelModel:
    """``P⁻¹`` with a coarse Gauss–Newton correction, as the quasi-Newton initial inverse Hessian.

    Passed as ``model`` to :meth:`igljoin.solve.LocalGlobalSolver.run`. At
    the first iteration it groups the free vertices into clusters; then, at
    the first iteration and again whenever a free vertex's fitted rotation
    has turned by more than ``rebuild_angle`` since the last build, it
    builds the clusters' motions ``A`` at the current positions (six rigid
    ones, and three bending ones with ``bending``) and factors
    ``A_c = Aᵀ H A`` (``H``: the Gauss–Newton model at the current
    iterate). ``P``'s factorization is the solver's own, reused.

    A coarse space built once points the wrong way once the guest has
    turned far from where it was built (its turns are about the old
    centroids and axes, its stiffnesses those of the old edge directions):
    on a bending tube the steps it proposes are then too long and the line
    search rejects most of them. Rebuilding keeps it aligned; the
    quasi-Newton pairs are kept across a rebuild (a different initial
    inverse Hessian under the same pairs is still a descent model).

    The defaults (rigid motions, built once) are what the join option
    ``preconditioner="two-level"`` uses; ``"auto"`` uses :data:`AUTO_MODEL`
    from :data:`AUTO_FROM_VERTICES` free vertices: with ``bending`` and
    ``rebuild_angle=0.2`` the iteration counts are lower still and no longer
    grow on the patch (35 / 30 / 41 / 55 at 10k / 20k / 40k / 100k against
    100 / 134 / 228 / 248), and on the tube they grow more slowly (73 / 162 /
    203 / 230 against 199 / 342 / 486 / 746). A rebuild computes
    values only — the operators' cluster patterns and ``A_c``'s are the
    first build's — and factors ``A_c`` anew: about 1 s at 100k guest
    vertices with the band rows kept apart (below; 4 s at 300k). Rebuilds in the
    first iterations, while the guest still moves far, led the paper's
    longer patch (compressed into its hole) to another stationary point 1 %
    higher in energy;
    ``first_rebuild=6`` keeps it at the default's minimum.

    A term whose rows each reach many clusters — the smooth join's band
    rows, ~14k guest vertices each on a 1M-vertex tube — would make ``A_c``
    dense among the band's clusters (``(J A)ᵀ W (J A)`` couples every
    cluster pair a row reaches) and its factorization denser still. With
    Pardiso such a term's rows ``J A`` (one per band row, ``w`` entries per
    cluster it reaches) are kept beside the rest ``S`` of ``A_c`` and the
    augmented system ``[[S, (J A)ᵀ], [J A, −W⁻¹]]`` is factored instead
    (:class:`igljoin.linsolve.AugmentedQuadratic`): the same ``A_c⁻¹``,
    without the dense block. Before anything is built, the entries the model
    will hold are counted (:attr:`model_entries`); above
    :data:`MAX_MODEL_ENTRIES` the model is refused (an ``OptionsError``) or,
    with ``fall_back`` and above :data:`AUTO_MAX_MODEL_ENTRIES`, stays the
    factored ``P`` (:attr:`fallback` says why).

    What a build keeps: the coarse system and its factorization, the
    operators' cluster patterns and every free vertex's motions
    (:attr:`motions`; ``A`` and ``Aᵀ`` are applied from them). The
    Gauss–Newton model's factors are never formed for the additive form; the
    balancing form keeps them (:attr:`factors`) for its products with ``H``.
    A rebuild lets the last factorization go before it makes the next.

    Parameters
    ----------
    solver : LocalGlobalSolver
        Supplies the terms, the fixed vertices, ``P``'s factorization and
        the backend.
    cluster_size : int
        Free vertices per cluster aimed at (coarse unknowns: 6 per cluster,
        9 with ``bending``).
    balancing : bool
        The balancing form ``C + (I − C H) P⁻¹ (I − H C)`` instead of the
        additive ``P⁻¹ + C``: fewer iterations, two products with ``H`` more
        per step.
    bending : bool
        Add every cluster's three bending motions
        (:func:`bending_prolongation`): the soft modes of a thin tube (its
        cross-sections turning oval) are smooth bendings that piecewise
        rigid motions approximate only at a high energy.
    rebuild_angle : float or None
        Radians a vertex's rotation may turn from its value at the last
        build before the coarse space is rebuilt; ``None``: built once.
    max_rebuilds : int or None
        Rebuilds allowed in a run after its first build (``None``: no
        limit).
    first_rebuild : int
        Earliest iteration of a run at which a rebuild is made (a kept
        model's rebuild at a run's start excepted, see :meth:`refresh`).
    fall_back : bool
        When the model would hold more than :data:`MAX_MODEL_ENTRIES`
        entries (:data:`AUTO_MAX_MODEL_ENTRIES` with ``fall_back``), or its
        coarse system cannot be factored soundly: keep the factored ``P``
        alone (``True``, what ``preconditioner="auto"`` asks) instead of
        raising ``OptionsError`` or ``SolveError``.

    Attributes
    ----------
    labels : ndarray of int64, shape (n_free,)
        Cluster of every free vertex (after the first refresh).
    factorizations : int
        Coarse factorizations made (builds).
    built_at : list of int
        Iteration of every build (of every run it served: a model kept
        across solves counts on).
    seconds : dict
        ``clusters``, ``model`` (the Gauss–Newton model's values, and the
        balancing form's factors), ``coarse`` (``Aᵀ H A``) and ``factor``
        times, summed over the builds (of every run it served).
    spec : tuple or None
        What :func:`preferred_model` made it from (``None`` when made
        directly): a kept model serves a later solve with the same.
    unsound : bool
        Its coarse system could not be factored soundly at some build (the
        ``fallback`` then says so): :func:`preferred_model` does not keep it.
    coarse_entries : int or None
        Entries of the coarse system counted at the first refresh (an upper
        bound with band rows kept apart: their rows of zero weight are left
        out of the factorization).
    model_entries : int or None
        Those, one per entry of the terms' operators (their cluster
        patterns), ``3 w`` per free vertex (its motions) and, for the
        balancing form, the Gauss–Newton model's factors' entries.
    motions : ndarray, shape (n_free, 3, w), or None
        Every free vertex's rows of ``A`` (:attr:`A` assembles them), ``w``
        = 6, or 9 with ``bending``.
    left_out : ndarray of int64
        Coarse unknowns of the latest build whose motions are left out (zero
        columns of ``A``, their coarse unknown apart with a diagonal of
        ``A_c``'s mean size): the bending motions of clusters of fewer than
        six vertices whose rigid motions span them to rounding
        (:data:`SPANNED_BENDING`).
    factors : list or None
        The balancing form's :func:`igljoin.newton.gauss_newton_factors`.
    fallback : str or None
        Why the coarse correction was not built or given up (``fall_back``
        and too many entries, or a coarse system that could not be factored
        soundly, at the first build or a rebuild): the model is then ``P⁻¹``
        alone for the rest of its use; ``None`` otherwise.
    """

    def __init__(
        self,
        solver,
        cluster_size: int = 20,
        balancing: bool = False,
        bending: bool = False,
        rebuild_angle: float | None = None,
        max_rebuilds: int | None = None,
        first_rebuild: int = 1,
        fall_back: bool = False,
    ):
        self.solver = solver
        self.cluster_size = int(cluster_size)
        self.balancing = bool(balancing)
        self.bending = bool(bending)
        self.rebuild_angle = None if rebuild_angle is None else float(rebuild_angle)
        self.max_rebuilds = None if max_rebuilds is None else int(max_rebuilds)
        self.first_rebuild = int(first_rebuild)
        self.fall_back = bool(fall_back)
        self.fallback = None
        self.coarse_entries = None
        self.model_entries = None
        self.built_at = []
        self.free_dofs = dofs(solver.free)
        self.labels = None
        self.left_out = np.zeros(0, dtype=np.int64)
        self._cache = {}
        # set at the first build: the free vertices' rows in the motions, per term its
        # operators' cluster patterns and whether it is kept apart, the blocks of A_c; at
        # every build the motions (n_free, 3, w)
        self._where = None
        self._wide = None
        self._patterns = None
        self._blocks = None
        self._clusters = None
        self.motions = None
        self.factors = None
        self.built_rotations = None
        self.coarse_factor = None
        self.factorizations = 0
        # factorizations before the current run's first build (max_rebuilds counts per run)
        self._run_base = 0
        # what preferred_model made it from (None when made directly)
        self.spec = None
        # its coarse system failed to factor soundly at some state (fallback says so)
        self.unsound = False
        self.seconds = {"clusters": 0.0, "model": 0.0, "coarse": 0.0, "factor": 0.0}

    def turned(self, state) -> float:
        """Largest angle (radians) a free vertex's rotation turned since the last build."""
        if self.built_rotations is None or state.rotations is None:
            return 0.0
        R = state.rotations[self.solver.free]
        # the angle of R R0ᵀ from its trace, 1 + 2 cos(angle)
        trace = np.einsum("nij,nij->n", R, self.built_rotations)
        return float(np.arccos(np.clip(0.5 * (trace.min() - 1.0), -1.0, 1.0)))

    def refresh(self, state, iteration: int) -> bool:
        """Build the coarse correction at ``state`` when due.

        ``iteration`` 1 starts a run. A model already built (kept from an
        earlier run, see :func:`preferred_model`) is rebuilt there if a free
        vertex's rotation at the start has turned more than ``rebuild_angle``
        from the last build (always with ``rebuild_angle=None``: built once per
        run), whatever ``first_rebuild`` says: a new model would be built at
        the same place. ``first_rebuild`` and ``max_rebuilds`` count within
        the run.

        Returns ``True`` at the first build only (the solver then drops its
        quasi-Newton memory: none yet, or the pairs a re-solve along a path
        started with — valid under another initial inverse Hessian too, so
        only work lost); a rebuild at a later run's start keeps them.
        """
        first = self.labels is None
        if self.fallback is not None:
            return False
        if not first and iteration <= 1:
            # a new run of a model built before (kept across solves): the start is where a
            # new model would be built, so first_rebuild does not hold it back; it is rebuilt
            # there unless its rotation test finds the start near its build (built once,
            # rebuild_angle=None, is once per run). The run's own count starts with the
            # build it starts on
            if (
                self.coarse_factor is not None
                and self.rebuild_angle is not None
                and self.turned(state) <= self.rebuild_angle
            ):
                self._run_base = self.factorizations - 1
                return False
        elif not first:
            if (
                self.rebuild_angle is None
                or iteration < self.first_rebuild
                or (
                    self.max_rebuilds is not None
                    and self.factorizations - self._run_base > self.max_rebuilds
                )
            ):
                return False
            if self.turned(state) <= self.rebuild_angle:
                return False
        if iteration <= 1:
            self._run_base = self.factorizations
        ls = self.solver
        t0 = time.perf_counter()
        X = state.X[ls.free]
        if first:
            # the factored form's free block as the graph: with the band rows solved through
            # the augmented system (ls.wide) their dense block is never formed, and the
            # other terms' block connects the mesh just as well
            graph = ls.factor.Qff if ls.wide is None else ls.factor.Sff
            self.labels = clusters(X, graph, self.cluster_size)
            vertex_labels = np.full(ls.n, -1, dtype=np.int64)
            vertex_labels[ls.free] = self.labels
            self._where = np.full(ls.n, -1, dtype=np.int64)
            self._where[ls.free] = np.arange(len(ls.free))
            self._clusters = int(self.labels.max()) + 1
            self._wide = self._count(self._clusters, 9 if self.bending else 6, vertex_labels)
        if self.model_entries > self._limit()[1]:
            # at every build (a model refused before is refused again), before any is made
            self.seconds["clusters"] += time.perf_counter() - t0
            message = self._too_large()
            if not self.fall_back:
                raise OptionsError(message)
            self.fallback = message
            self._let_go()
            return False
        t1 = time.perf_counter()
        # a rebuild lets the last factorization go first: the two together are the
        # build's peak (a 1M tube's coarse factorization holds ~5 GB)
        self.coarse_factor = self.factors = None
        blocks = _rigid_blocks(X, self.labels)
        self.left_out = np.zeros(0, dtype=np.int64)
        if self.bending:
            blocks = np.concatenate([blocks, _bending_blocks(X, self.labels)], axis=2)
            spanned = _spanned_bending(blocks, self.labels, self._clusters)
            if spanned.size:
                # their columns zero: A_c's rows for them are zero but for the diagonal
                # _project gives them, and the coarse solve leaves them at zero
                blocks[np.isin(self.labels, spanned), :, 6:] = 0.0
                self.left_out = (9 * spanned[:, None] + np.arange(6, 9)).ravel()
        self.motions = np.ascontiguousarray(blocks)
        del blocks
        model = 0.0
        if self.balancing:
            # the balancing form's products with H need the factors themselves
            t2 = time.perf_counter()
            self.factors = gauss_newton_factors(ls.terms, state, ls.n, self._cache)
            model = time.perf_counter() - t2
        coarse, values = self._project(state)
        model += values
        t3 = time.perf_counter()
        try:
            self.coarse_factor = self._factor(*coarse)
        except SolveError as exc:
            if not self.fall_back:
                raise
            # a coarse system Pardiso cannot factor soundly (pivots perturbed, its probe
            # solve off): "auto" goes on with P alone, as past its size limit
            self.fallback = f"{exc}; the iteration went on with the factored form alone"
            # the values, not the set-up, failed: a later solve makes a new model
            self.unsound = True
            self._let_go()
            self._book(t1 - t0, t3 - t1, model, time.perf_counter() - t3)
            return False
        self.factorizations += 1
        self.built_at.append(int(iteration))
        if state.rotations is not None:
            self.built_rotations = state.rotations[ls.free].copy()
        self._book(t1 - t0, t3 - t1, model, time.perf_counter() - t3)
        return first

    def _let_go(self) -> None:
        """Drop what only builds read once the model has fallen back to ``P`` alone.

        Its :attr:`fallback` is then never cleared: the count's patterns and the
        model's cache (at 1M guest vertices 0.73 GB) would be held unread to the end of
        its use.
        """
        self.motions = self.factors = None
        self._patterns = self._blocks = None
        self._cache = {}

    def _book(self, clusters: float, coarse: float, model: float, factor: float) -> None:
        """Add a build's seconds to :attr:`seconds`: ``coarse`` includes ``model`` (the
        model's values and the balancing form's factors), booked apart from the projection."""
        self.seconds["clusters"] += clusters
        self.seconds["coarse"] += coarse - model
        self.seconds["model"] += model
        self.seconds["factor"] += factor

    def _augmented(self) -> bool:
        """Whether wide terms may be kept apart (the augmented system needs Pardiso)."""
        ls = self.solver
        return ls.linear_solver in ("auto", "pardiso") and "pardiso" in available_backends()

    def _count(self, a: int, w: int, vertex_labels: np.ndarray) -> list:
        """Which terms are wide; finds the patterns and counts the entries the model will hold.

        ``vertex_labels`` (n,) gives every vertex's cluster (-1 for a fixed one).

        Only the operators' patterns and the clusters are read: every row of a
        term's operator ``K`` (and of the Laplacian ``L`` of a rotation-aware
        shape term) reaches some clusters (:func:`igljoin.coarse_kernels.row_clusters`,
        kept for the projections); ``A_c``'s local blocks are those of
        ``Tᵀ T`` for the clusters' incidence ``T`` of the local rows
        (:func:`igljoin.coarse_kernels.block_pattern`), ``w²`` entries each;
        a wide term adds ``w`` entries per cluster each of its factor rows
        reaches (:func:`igljoin.newton.row_directions` rows per row of ``K``).

        Returns
        -------
        list of bool
            Per term of the solver: kept as rows of ``J A``.
        """
        augmented = self._augmented()
        local, wide, wide_entries, operators = [], [], 0, 0
        self._patterns = []
        for term in self.solver.terms:
            of_K, count, nnz = _operator_clusters(term, vertex_labels)
            of_L = None
            reach = len(of_K[1])
            operators += nnz
            if isinstance(term, ShapeTerm) and term.rotation_aware:
                (Lptr, Lind, _), *_ = rotation_pattern(term, self._cache)
                of_L = ck.row_clusters(Lptr, Lind, vertex_labels, 1)
                reach, count = reach + len(of_L[1]), count + len(Lptr) - 1
                operators += len(Lind)
            # the eliminated rotations' factor enters with a minus sign: never kept apart
            keep_apart = (
                augmented
                and not isinstance(term, ShapeTerm)
                and reach >= _WIDE_CLUSTERS * max(count, 1)
            )
            wide.append(bool(keep_apart))
            if keep_apart:
                wide_entries += row_directions(term) * w * reach
            else:
                local += [p[:2] for p in (of_K, of_L) if p is not None]
            self._patterns.append((of_K, of_L))
        self._blocks = ck.block_pattern(local, a)
        self.coarse_entries = int(w * w * len(self._blocks[1]) + wide_entries)
        # besides the coarse system: the operators' cluster patterns, every free vertex's
        # motions and, for the balancing form, the factors themselves. Of the patterns only
        # the slots (one per operator entry) are counted, not row_clusters' lists of the
        # clusters each row reaches nor their row pointers (together 26-32 % of the count
        # of the bending model on 1k-10k tubes and patches): the bytes per entry of
        # MAX_MODEL_ENTRIES's comment were measured against the count without them, so
        # the memory they take is inside those bytes; counting them now would move every
        # measured count and limit with it
        held = operators + 3 * w * len(self.labels)
        if self.balancing:
            held += sum(factor_entries(t) for t in self.solver.terms)
        self.model_entries = self.coarse_entries + held
        return wide

    def _limit(self) -> tuple:
        """The count past which this model is not built, ``(name, value)``.

        Read when it is counted (a changed module value applies).
        """
        if self.fall_back:
            return "AUTO_MAX_MODEL_ENTRIES", AUTO_MAX_MODEL_ENTRIES
        return "MAX_MODEL_ENTRIES", MAX_MODEL_ENTRIES

    def _too_large(self) -> str:
        """The refusal's message: the count, the limit and the ways out."""
        pardiso = (
            ""
            if self._augmented()
            else "linear_solver='auto' with Pardiso installed (the smooth join's band rows "
            "are then kept out of the coarse matrix), "
        )
        name, limit = self._limit()
        gb = _BYTES_PER_ENTRY * self.model_entries / 1e9
        size = f"{gb:.0f}" if gb >= 1 else f"{gb:.2g}"
        return (
            f"the two-level preconditioner's model would hold {self.model_entries:,} entries "
            f"(its coarse system {self.coarse_entries:,}), more than "
            f"igljoin.twolevel.{name} = {limit:,} (about {size} GB at its first build): use "
            "preconditioner='factored' (or 'auto', which then keeps the factored form), "
            f"{pardiso}or raise igljoin.twolevel.{name}"
        )

    def coarse_matrix(self) -> sp.csr_matrix:
        """``A_c`` assembled, shape (w a, w a) — for checks on small meshes.

        With wide terms kept apart it is formed here from the augmented
        factorization's parts, ``S + (J A)ᵀ W (J A)``.
        """
        f = self.coarse_factor
        if isinstance(f, AugmentedQuadratic):
            return sp.csr_matrix(f.Sff + f.Kft @ sp.diags(f.cw) @ f.Kf)
        return f.Qff

    def _factor(self, Ac: sp.csr_matrix, U=None, weights=None):
        """Factor ``A_c`` anew (its pattern is the same at every build; its values are not).

        With wide rows ``U = J A`` (weights ``W``) ``A_c`` is ``S + Uᵀ W U``
        for the local part ``S`` passed as ``Ac``: the augmented system is
        factored instead. Otherwise Pardiso factors ``A_c`` where it may be
        used (at 40k guest vertices 0.59 s against 2.7 s for cholespy's),
        else the solver's backend. Pardiso's numeric phase alone on the first
        build's analysis (0.17 s at 40k) crashed inside MKL on a rebuild of a
        100k tube's coarse matrix, so every build is a whole factorization.
        As observed on the 30k patch's fine system and the 100k patch's
        coarse one (the crash itself was met on a 100k tube's), the numeric
        phase ends in a segmentation fault after a back-solve made on fewer
        threads than the factorization's (as every back-solve here is made,
        on one), and not after back-solves on the factorization's threads.
        """
        ls = self.solver
        if U is not None:
            return _CoarseAugmented(Ac, U, weights)
        backend = "pardiso" if self._augmented() else ls.linear_solver
        return FixedQuadratic(Ac, np.zeros(0, dtype=np.int64), backend)

    def _project(self, state) -> tuple:
        """``A_c = Aᵀ H A`` from the terms' factor rows, plus the ridge; shape (w a, w a).

        Term after term, the model's values at ``state``
        (:func:`igljoin.newton.factor_rows`) are projected onto the motions
        without forming the factors ``J``
        (:func:`igljoin.coarse_kernels.project_rows`,
        :func:`igljoin.coarse_kernels.project_rotation`), on the patterns
        found at the first build. The wide terms' rows are not projected but
        kept as rows ``J A`` (:func:`igljoin.coarse_kernels.motion_rows_of`).

        Returns
        -------
        coarse : (scipy.sparse.csr_matrix, scipy.sparse.csr_matrix or None, ndarray or None)
            ``(S, U, weights)``: ``S`` of shape (w a, w a), ``A_c`` (its local
            part with wide terms), ridge included; ``U`` of shape (rows, w a),
            the wide terms' rows ``J A``, and their ``weights`` (rows,).
        seconds : float
            Time spent on the model's values (:func:`igljoin.newton.factor_rows`).
        """
        ls = self.solver
        a = self._clusters
        B = self.motions
        w = B.shape[2]
        where = self._where
        bptr, bcols, lower, upper = self._blocks
        out = np.zeros((len(bcols), w, w))
        wide_rows, wide_weights = [], []
        seconds = 0.0
        for term, (of_K, of_L), wide in zip(ls.terms, self._patterns, self._wide):
            # a stacked operator (counted block by block) is made here, where it is read
            K = sp.csr_matrix(term.K)
            t0 = time.perf_counter()
            (_, directions, weights), rotation = factor_rows(term, state, self._cache)
            seconds += time.perf_counter() - t0
            weights = np.ascontiguousarray(weights, dtype=np.float64)
            directions = (
                np.zeros((0, 3, 3))
                if directions is None
                else np.ascontiguousarray(directions, dtype=np.float64)
            )
            args = (K.indptr, K.indices, K.data, directions)
            if wide:
                values = ck.motion_rows_of(*args, of_K[0], of_K[2], where, B)
                wide_rows.append(_motion_matrix(values, of_K[0], of_K[1], weights.shape[1], w, a))
                wide_weights.append(weights.ravel())
            else:
                ck.project_rows(*args, weights, *of_K, bptr, bcols, where, B, out)
            if rotation is not None:
                (Lptr, Lind, _), *_ = rotation_pattern(term, self._cache)
                ck.project_rotation(Lptr, Lind, rotation, *of_L, bptr, bcols, where, B, out)
        out[lower] = out[upper].transpose(0, 2, 1)
        Ac = sp.bsr_matrix((out, bcols, bptr), shape=(w * a, w * a)).tocsr()
        del out
        diagonal = Ac.diagonal()
        U = weights = None
        if wide_rows:
            U = wide_rows[0] if len(wide_rows) == 1 else sp.vstack(wide_rows, format="csr")
            weights = np.concatenate(wide_weights)
            # the diagonal of Uᵀ W U: the ridge is relative to the whole A_c's
            diagonal = diagonal + np.bincount(
                U.indices,
                U.data**2 * np.repeat(weights, np.diff(U.indptr)),
                minlength=w * a,
            )
        ridge = _RIDGE * diagonal.mean()
        if self.left_out.size:
            # a left-out motion's unknown stands alone: a diagonal of A_c's mean size keeps
            # its pivot sound (its right-hand side, and so its value, is always zero)
            ridge = np.full(len(diagonal), ridge)
            ridge[self.left_out] = diagonal.mean()
        Ac.setdiag(Ac.diagonal() + ridge)
        return (Ac, U, weights), seconds

    @property
    def A(self) -> sp.csr_matrix:
        """The clusters' motions ``A`` assembled, shape (3 n_free, w a) — for checks.

        The model keeps them as :attr:`motions` (n_free, 3, w) and applies
        ``A`` and ``Aᵀ`` from there.
        """
        return _cluster_columns(self.motions, self.labels, self._clusters)

    def _coarse(self, v: np.ndarray) -> np.ndarray:
        """``A A_c⁻¹ Aᵀ v`` for ``v`` of shape (3 n_free,)."""
        B, labels = self.motions, self.labels
        coarse = ck.restrict(B, labels, v, self._clusters)
        return ck.prolong(B, labels, self.coarse_factor.solve_free(coarse[:, None])[:, 0])

    def _coarse_beside(self, v: np.ndarray, work) -> tuple:
        """``(work(), A A_c⁻¹ Aᵀ v)``, the second made on another thread while ``work`` runs.

        ``work`` (the fine back-solve) runs in this thread; :meth:`_coarse` of
        ``v`` (3 n_free,) on the coarse solves' worker thread (one for the
        process, started on first use: handing it a solve costs ~10 µs,
        starting a thread per solve ~0.5 ms). Both results are returned once
        both have finished; an exception in either is raised here, after the
        coarse solve has finished.
        """
        coarse = _coarse_worker().submit(self._coarse, v)
        try:
            z = work()
        finally:
            done = coarse.exception()  # waits for it
        if done is not None:
            raise done
        return z, coarse.result()

    def _model(self, v: np.ndarray) -> np.ndarray:
        """``H_ff v`` for ``v`` of shape (3 n_free,), from the factored model."""
        return factors_product(self.factors, self.free_dofs, self.solver.n, v)

    def solve_free(self, v: np.ndarray) -> np.ndarray:
        """The preconditioner's inverse on ``v`` (n_free, 3); returns shape (n_free, 3).

        The additive form's two solves are independent: from
        :data:`CONCURRENT_FROM_VERTICES` free vertices the coarse one
        (:meth:`_coarse`) runs on a second thread while this one makes the
        fine back-solve (the coarse side does not wait for the GIL whatever
        the fine backend holds: Pardiso through ctypes, the compiled ``Aᵀ`` and
        ``A`` without it), and the two are added as before, so the
        result is the same floats. On the 100k patch the fine back-solve
        takes ~60 ms and the coarse ~22 ms an iteration, one core each: the
        two together 64 against 90 ms one after the other, a join's
        back-solves 3.6 against 5.2 s (two cores, load 1-2). Two MKL threads
        for either solve instead were no faster in all (fine 49, coarse 12 ms).
        """
        fine = self.solver.factor.solve_free
        v = np.ascontiguousarray(v, dtype=np.float64)
        flat = v.reshape(-1)
        if self.fallback is not None:
            return fine(v)
        if not self.balancing:
            if len(self.solver.free) >= CONCURRENT_FROM_VERTICES:
                z, c = self._coarse_beside(flat, lambda: fine(v))
            else:
                z, c = fine(v), self._coarse(flat)
            return z + c.reshape(v.shape)
        c = self._coarse(flat)
        z = fine((flat - self._model(c)).reshape(v.shape)).reshape(-1)
        return (c + z - self._coarse(self._model(z))).reshape(v.shape)


#: Free guest vertices from which ``preconditioner="auto"`` uses :data:`AUTO_MODEL`
#: (``pipelines/coarse_study.py time``, one BLAS thread, the iteration's seconds with it
#: over those with ``P`` alone: tube / patch 0.9-1.1 / 0.7-1.2 at 10k, 0.90-0.96 / 0.55-0.63
#: at 20k, 0.69-0.96 / 0.40-0.42 at 40k, 0.71 / 0.51-0.58 at 100k). Below, it was measured
#: again with the model projected from the operator rows (four runs, load 0.5-2): 5k tube /
#: patch 1.17-1.24 / 1.12-1.75, 10k 0.96-1.06 / 0.94-1.04; on the six paper samples
#: (1.1k-2.4k free vertices, ``coarse_study.py paper``) the whole join's median 1.42x
#: ``P``'s (132 to 188 ms), 1.12x built once: it halves the end-to-end tubes' iterations
#: (107 / 102 to 60 / 52) but a build costs 17-24 ms there (9-11 on the patches), about what
#: those iterations cost, it saves little on the patches (35 / 54 to 31 / 40) and nothing on
#: the longer tube, and the longer patch rebuilds it 33 times (or, built once, needs 275
#: iterations against 235).
AUTO_FROM_VERTICES = 20_000

#: The two-level model ``preconditioner="auto"`` uses from :data:`AUTO_FROM_VERTICES`:
#: bending motions, rebuilt once a rotation has turned 0.2 rad, never before the sixth
#: iteration (earlier rebuilds, while the guest still moves far, led the paper's longer
#: patch to another stationary point, 1 % higher).
AUTO_MODEL = {"bending": True, "rebuild_angle": 0.2, "first_rebuild": 6}


def _model_spec(solver, options):
    """What :func:`preferred_model` makes for ``options``: ``None`` (``P`` alone) or
    ``(choice, keyword arguments, entry limit)``, the module values read now."""
    choice = options.preconditioner
    if options.acceleration == 0 or choice == "factored":
        return None
    if choice == "two-level":
        return ("two-level", (), MAX_MODEL_ENTRIES)
    if len(solver.free) >= AUTO_FROM_VERTICES:
        kwargs = (*sorted(AUTO_MODEL.items()), ("fall_back", True))
        return ("auto", kwargs, AUTO_MAX_MODEL_ENTRIES)
    return None


def preferred_model(solver, options, kept=None):
    """The quasi-Newton model a join uses for ``options.preconditioner``.

    Parameters
    ----------
    solver : LocalGlobalSolver
        The join's iteration (its free vertices count).
    options : JoinOptions
    kept : TwoLevelModel, optional
        A model this function made before (for an earlier solve): returned
        itself, with its clusters, patterns and factorization, when it was
        made on ``solver`` for the same choice (the same preconditioner and
        the same module values :data:`AUTO_MODEL` and the entry limits) and
        its coarse system did not fail to factor; a new model otherwise.
        Its next :meth:`TwoLevelModel.refresh` at iteration 1 rebuilds it
        if the new start has turned from its last build.

    Returns
    -------
    TwoLevelModel or None
        ``None`` (the factored ``P`` alone) for ``"factored"``, for
        ``acceleration=0`` and for ``"auto"`` below
        :data:`AUTO_FROM_VERTICES` free vertices; the rigid coarse space
        built once for ``"two-level"`` (refused with ``OptionsError`` at
        its first refresh past :data:`MAX_MODEL_ENTRIES`); :data:`AUTO_MODEL`
        for ``"auto"`` from :data:`AUTO_FROM_VERTICES` on, which past
        :data:`AUTO_MAX_MODEL_ENTRIES` stays ``P`` alone and says so in its
        ``fallback``.
    """
    spec = _model_spec(solver, options)
    if spec is None:
        return None
    if kept is not None and kept.solver is solver and kept.spec == spec and not kept.unsound:
        return kept
    model = TwoLevelModel(solver, **dict(spec[1]))
    model.spec = spec
    return model
