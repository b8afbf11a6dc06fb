"""Energy terms of the join (paper §4.2–4.4).

A term is a constant sparse operator ``K`` (rows × n), a weight per row and a
``target(X)`` that the local step recomputes; its energy is
``Σ_r w_r ‖(K X)_r − target_r‖²``. The solver only sees these three things,
so adding a term never touches the solver.

* :class:`ShapeTerm` — Laplacian coordinates (Eq. 3–4), rotated per vertex by
  a rotation fitted in the local step (rotation-aware), or fixed as in the
  paper.
* :class:`StretchTerm` — edge lengths kept with stiffness ``k_ij`` (Eq. 5–6).
* :class:`SmoothJoinTerm` — the guest leaves the seam along the host surface
  continued across it (Eq. 7): the paper's tangential-point form, or a robust
  form acting on every cross-seam edge.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import igl
import numpy as np
import scipy.sparse as sp

from . import kernels
from .bandfit import BAND_EDGES
from .errors import OptionsError
from .frames import SeamFrames, face_normals_areas, unit, vertex_face_matrix
from .rotations import fit_rotations, fit_rotations_igl

#: Weight ``μ`` of the one-ring edges in the rotation-aware shape term, relative to
#: the Laplacian. Small: it only fixes the rotations and makes them exact minimisers.
ROTATION_REGULARISATION = 0.1

#: Weight of one band row of the smooth-join term in cross-seam edges of the robust
#: form: a seam vertex of a regular mesh has about two to three such edges.
ROWS_PER_BAND_ROW = 2.5

#: Size guard of the smooth join's band rows: the vertex pairs they couple, i.e. the
#: non-zeros of their block ``Kᵀ W K`` in the quadratic form and the preconditioner
#: (about 12 bytes each per matrix, before the factor's fill). The band is a width in
#: mesh units, so a guest much finer than the host puts ever more vertices under each
#: row: 5.7e5 pairs at 10k guest vertices on the paper's patch host, 3.5e7 at 100k,
#: about 3e9 (tens of GB) for a 1M-vertex tube. It applies where the block is formed
#: (:meth:`SmoothJoinTerm.quadratic`): not when the solver keeps it out of its matrices
#: (:data:`igljoin.solve.AUGMENT_FROM_COUPLINGS`). Change with
#: ``igljoin.terms.MAX_BAND_COUPLINGS``.
MAX_BAND_COUPLINGS = 200_000_000

__all__ = [
    "check_order",
    "Term",
    "LocalState",
    "ShapeTerm",
    "StretchTerm",
    "SmoothJoinTerm",
    "unique_edges",
    "difference_operators",
    "row_patterns",
    "edge_stiffness",
    "band_couplings",
    "MAX_BAND_COUPLINGS",
]


@dataclass
class LocalState:
    """What the local step shares between terms for one iterate ``X`` (n, 3).

    Attributes
    ----------
    X : ndarray, shape (n, 3)
        The iterate (C-contiguous float64).
    rotations : ndarray, shape (n, 3, 3), optional
        Per-vertex rotations fitted at ``X`` (set by the rotation-aware shape term).
    cache : dict
        Products such as ``K X`` computed once per local step.
    hint : ndarray, shape (n, 3, 3), optional
        Rotations of a nearby iterate (the previous local step's
        ``rotations``) to start the rotation fit from; they change only how
        fast it converges.
    """

    X: np.ndarray
    rotations: np.ndarray | None = None
    cache: dict = field(default_factory=dict)
    hint: np.ndarray | None = None


class Term(ABC):
    """One quadratic-in-X energy term with a recomputed target.

    Subclasses set ``K`` (rows × n), ``weights`` (rows,) and :meth:`target`;
    :meth:`local` and :meth:`quadratic` have generic implementations that a
    term may replace by faster equivalents.
    """

    name: str
    K: sp.csr_matrix
    weights: np.ndarray

    #: Factor of this term's ``Kᵀ W K`` in the quasi-Newton preconditioner
    #: (:class:`igljoin.solve.LocalGlobalSolver`). 1 for a term whose Hessian
    #: is ``Kᵀ W K`` everywhere; smaller for a term whose target is a
    #: projection and so is stiff in only some directions.
    preconditioner_scale: float = 1.0

    #: The term's local step fits per-vertex rotations and stores them in
    #: ``LocalState.rotations`` for the terms after it.
    sets_rotations: bool = False

    #: The term's local step reads ``LocalState.rotations`` when a term before it
    #: set them (and works without them when none did).
    reads_rotations: bool = False

    @abstractmethod
    def target(self, state: LocalState) -> np.ndarray:
        """Target of ``K X``, shape (rows, 3), for the current iterate."""

    @property
    def rows(self) -> int:
        """Number of rows of ``K``."""
        return int(self.K.shape[0])

    @property
    def soft_rows(self) -> int:
        """Soft constraints per coordinate, counted as the paper counts them."""
        return self.rows

    def applied(self, state: LocalState) -> np.ndarray:
        """``K X`` at ``state.X``, shape (rows, 3), computed once per local step."""
        key = id(self)
        if key not in state.cache:
            state.cache[key] = self.K @ state.X
        return state.cache[key]

    def energy(self, state: LocalState, target: np.ndarray | None = None) -> float:
        """``Σ w ‖K X − target‖²`` at ``state.X``."""
        t = self.target(state) if target is None else target
        r = self.applied(state) - t
        return float(np.dot(self.weights, np.einsum("ij,ij->i", r, r)))

    def quadratic(self) -> sp.csr_matrix:
        """The term's constant quadratic form ``Kᵀ W K``, shape (n, n)."""
        return _gram(self.K, self.weights)

    def local(self, state: LocalState) -> tuple[float, np.ndarray]:
        """Local step: energy at ``state.X`` and ``Kᵀ W (K X − target)``, shape (n, 3).

        The second output is half the energy's gradient (every target is the
        closest point of ``K X`` in a fixed set, so the target's own change
        does not enter). Summed over the terms it is ``Q X − Σ Kᵀ W target``;
        the global step is ``X − Q⁻¹`` of it on the free vertices.
        """
        t = self.target(state)
        r = self.applied(state) - t
        e = float(np.dot(self.weights, np.einsum("ij,ij->i", r, r)))
        KtW = getattr(self, "_KtW", None)
        if KtW is None:
            KtW = self._KtW = _weighted_transpose(self.K, self.weights)
        return e, KtW @ r

    def local_into(self, state: LocalState, G: np.ndarray) -> float:
        """:meth:`local` adding its half gradient into ``G`` (n, 3); returns the energy.

        The solver sums the terms' half gradients this way; a compiled term
        adds into ``G`` directly instead of making an array of its own.
        """
        e, g = self.local(state)
        G += g
        return e

    def _local_from_into(self, state: LocalState) -> tuple[float, np.ndarray]:
        """:meth:`local` of a term that adds in place: ``local_into`` on a zero (n, 3) array."""
        G = np.zeros((state.X.shape[0], 3))
        return self.local_into(state, G), G


def check_order(terms: list[Term]) -> None:
    """Refuse a term list in which a term reads rotations a later term sets.

    The solver runs the local steps in list order, sharing one
    :class:`LocalState`; a term that reads ``state.rotations`` must come after
    the term that fits them, or it would read the previous iterate's.

    Parameters
    ----------
    terms : list of Term

    Raises
    ------
    ValueError
        Naming the two terms, if a rotation-reading term precedes a
        rotation-setting one (an internal ordering error, not a user's).
    """
    reader = next((t for t in terms if t.reads_rotations), None)
    if reader is None:
        return
    for setter in terms[terms.index(reader) + 1 :]:
        if setter.sets_rotations:
            raise ValueError(
                f"the {reader.name} term reads the rotations the {setter.name} term sets, "
                "so it must come after it in the term list"
            )


def _edges_key(E: np.ndarray) -> tuple:
    """Key of the edge vectors over ``E`` (e, 2) in ``LocalState.cache``."""
    return ("edges", id(E))


def _edge_vectors(
    state: LocalState, E: np.ndarray, D: sp.csr_matrix, compiled: bool = True
) -> np.ndarray:
    """``X[E[:, 0]] − X[E[:, 1]]``, shape (e, 3), shared by the terms using the same ``E``."""
    key = _edges_key(E)
    if key not in state.cache:
        state.cache[key] = kernels.edge_vectors(state.X, E) if compiled else D @ state.X
    return state.cache[key]


def unique_edges(F: np.ndarray) -> np.ndarray:
    """Undirected edges of a triangle mesh, shape (e, 2), each listed once."""
    return np.asarray(igl.edges(F), dtype=np.int64)


def _gram(K: sp.spmatrix, weights: np.ndarray) -> sp.csr_matrix:
    """``Kᵀ diag(weights) K``, shape (n, n), for ``K`` of shape (r, n): the floats and the
    layout of ``sp.csr_matrix(K.T @ sp.diags(weights) @ K)``, in one product.

    That expression multiplies ``w[r] K[r, i]`` by ``K[r, j]`` and sums over the
    rows ``r`` in increasing order, through two transposed products and a
    conversion that sorts each row's columns; here ``Kᵀ``'s entries are scaled
    by their row's weight and multiplied by ``K`` once (the same products,
    summed in the same order), and the columns sorted. Later sums read the
    layout (a sparse product sums a row in its stored order), so it is kept too.
    A ``K`` with duplicate entries takes the expression itself.
    """
    K = sp.csr_matrix(K)
    if not K.has_canonical_format:
        return sp.csr_matrix(K.T @ sp.diags(weights) @ K)
    # the zeros _weighted_transpose leaves out add nothing to a sum, and a product's
    # entries that sum to zero are left out either way
    Q = sp.csr_matrix(_weighted_transpose(K, weights) @ K)
    Q.sort_indices()
    return Q


def _weighted_transpose(K: sp.spmatrix, weights: np.ndarray) -> sp.csr_matrix:
    """``Kᵀ diag(weights)``, shape (n, r), for ``K`` of shape (r, n): the floats and the
    layout of ``sp.csr_matrix(K.T @ sp.diags(weights))``, without the product.

    Each entry is one product ``K[r, i] w[r]``; ``Kᵀ``'s entries are scaled by
    their row's weight and those that come out zero dropped, as the product
    drops them (a row of weight 0 keeps no entry); the columns are sorted as
    the conversion from ``Kᵀ`` sorts them. A ``K`` with unsorted or duplicate
    entries takes the expression itself.
    """
    K = sp.csr_matrix(K)
    if not K.has_canonical_format:
        return sp.csr_matrix(K.T @ sp.diags(weights))
    KtW = sp.csr_matrix(K.T)
    KtW.data = KtW.data * np.asarray(weights, dtype=np.float64)[KtW.indices]
    KtW.eliminate_zeros()
    return KtW


def _difference_operator(E: np.ndarray, n: int) -> sp.csr_matrix:
    e = len(E)
    rows = np.repeat(np.arange(e), 2)
    vals = np.tile([1.0, -1.0], e)
    return sp.csr_matrix((vals, (rows, E.reshape(-1))), shape=(e, n))


def row_patterns(term: Term) -> tuple:
    """Matrices with the patterns of ``term``'s operator ``K``'s row blocks, in order.

    A term whose ``K`` is a stack it builds on first use (the rotation-aware
    :class:`ShapeTerm`) gives its blocks' patterns without stacking them
    (:attr:`ShapeTerm.row_patterns`); any other term ``(K,)``. Their entries,
    rows and the clusters or vertex pairs their rows reach are ``K``'s (not
    their values).

    Parameters
    ----------
    term : Term

    Returns
    -------
    tuple of scipy.sparse.csr_matrix
    """
    blocks = getattr(term, "row_patterns", None)
    return tuple(blocks) if blocks is not None else (sp.csr_matrix(term.K),)


def difference_operators(E: np.ndarray, n: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """The edges' difference operator ``D`` (``(D X)_e = X[E[e, 0]] − X[E[e, 1]]``) and ``Dᵀ``.

    Made once and passed to the terms that read them (the rotation-aware
    shape term's one-ring rows, the stretch term's ``K``), so that they share one.

    Parameters
    ----------
    E : ndarray of int64, shape (e, 2)
    n : int
        Vertices.

    Returns
    -------
    D : scipy.sparse.csr_matrix, shape (e, n)
    Dt : scipy.sparse.csr_matrix, shape (n, e)
    """
    D = _difference_operator(np.asarray(E, dtype=np.int64), n)
    return D, sp.csr_matrix(D.T)


def edge_stiffness(
    E: np.ndarray, F: np.ndarray, stiffness: np.ndarray | None, on: str
) -> np.ndarray:
    """Per-edge stiffness ``k_ij`` from a per-vertex or per-face array.

    Parameters
    ----------
    E : ndarray of int64, shape (e, 2)
    F : ndarray of int64, shape (m, 3)
    stiffness : ndarray, shape (n,) or (m,), or None
        ``None`` gives 1 everywhere.
    on : {"vertex", "face"}

    Returns
    -------
    ndarray, shape (e,)
        Vertex values: mean of the two endpoints. Face values: mean over the
        (one or two) faces sharing the edge.
    """
    if stiffness is None:
        return np.ones(len(E))
    if on == "vertex":
        return 0.5 * (stiffness[E[:, 0]] + stiffness[E[:, 1]])
    n = int(max(E.max(), F.max())) + 1
    key = np.minimum(E[:, 0], E[:, 1]) * n + np.maximum(E[:, 0], E[:, 1])
    fe = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fkey = np.minimum(fe[:, 0], fe[:, 1]) * n + np.maximum(fe[:, 0], fe[:, 1])
    fval = np.tile(stiffness, 3)
    order = np.argsort(key)
    pos = order[np.searchsorted(key[order], fkey)]
    total = np.bincount(pos, weights=fval, minlength=len(E))
    count = np.bincount(pos, minlength=len(E))
    return total / np.maximum(count, 1)


class ShapeTerm(Term):
    """Laplacian shape term ``w_L Σ ‖l(p′) − R_i l(p)‖²`` (Eq. 3–4), rotation-aware.

    With ``rotation_aware`` the energy of vertex ``i`` is

    ``w_L (‖l(p′)_i − R_i l(p)_i‖² + μ Σ_j ‖(p′_i − p′_j) − R_i (p_i − p_j)‖²)``

    and ``R_i`` is its exact minimiser over rotations (a weighted Procrustes
    fit of the Laplacian and the one-ring edges). The small one-ring part
    (``μ`` = :data:`ROTATION_REGULARISATION`) pins down the rotation about
    the Laplacian's own axis; because ``R_i`` minimises the very energy
    being minimised, every local and every global step lowers it, and the
    iteration settles on a minimum instead of drifting.

    Parameters
    ----------
    V0 : ndarray, shape (n, 3)
        Rest positions.
    F : ndarray of int64, shape (m, 3)
    weight : float
        ``w_L``.
    laplacian : {"uniform", "cotangent"}
        Uniform weights ``1/|N(p)|`` as in the paper, or cotangent weights
        normalised per row.
    rotation_aware : bool
        ``False`` keeps the paper's fixed Laplacian coordinates (no rotations).
    E : ndarray of int64, shape (e, 2), optional
        The mesh's unique edges (``unique_edges(F)``); pass the array the
        stretch term uses so that both share one ``D X`` per local step.
    differences : tuple of scipy.sparse.csr_matrix, optional
        ``difference_operators(E, n)``, shared with the stretch term (made here
        when not given).
    compiled : bool
        Run the local step by the compiled kernels (:mod:`igljoin.kernels`,
        default); ``False`` runs the numpy reference path, which the tests
        compare against.

    Notes
    -----
    The local step works in structure-of-arrays layout: covariances and
    rotations have shape (3, 3, n). Rotations are fitted by
    :func:`igljoin.rotations.fit_rotations`, started from ``state.hint``.
    """

    name = "shape"

    def __init__(
        self,
        V0,
        F,
        weight=1.0,
        laplacian="uniform",
        rotation_aware=True,
        E=None,
        compiled=True,
        differences=None,
    ):
        n = len(V0)
        self.n = n
        self.E = unique_edges(F) if E is None else np.asarray(E, dtype=np.int64)
        self.weight = float(weight)
        if laplacian == "cotangent":
            C = -igl.cotmatrix(V0, F).tocsr()
            diag = C.diagonal()
            L = sp.diags(1.0 / np.where(diag != 0, diag, 1.0)) @ C
        else:
            A = sp.csr_matrix(
                (np.ones(2 * len(self.E)), (self.E.reshape(-1), self.E[:, ::-1].reshape(-1))),
                shape=(n, n),
            )
            deg = np.asarray(A.sum(axis=1)).ravel()
            L = sp.eye(n, format="csr") - sp.diags(1.0 / np.maximum(deg, 1.0)) @ A
        self.L = sp.csr_matrix(L)
        self.Lt = sp.csr_matrix(self.L.T)
        self.delta = self.L @ V0
        self.rotation_aware = rotation_aware
        self.sets_rotations = bool(rotation_aware)
        self._K = None
        self.compiled = False
        if not rotation_aware:
            self._K = self.L
            self.weights = np.full(n, self.weight)
            return
        mu = ROTATION_REGULARISATION
        ne = len(self.E)
        self.D, self.Dt = differences or difference_operators(self.E, n)
        # rows: Laplacians, then one-ring edges i->j (owned by i) and j->i (owned by j)
        self.weights = np.concatenate([np.full(n, self.weight), np.full(2 * ne, self.weight * mu)])
        self.rest_edges = V0[self.E[:, 0]] - V0[self.E[:, 1]]
        self._covariance = None
        # arrays of the compiled local step (igljoin.kernels)
        self.compiled = bool(compiled)
        if self.compiled:
            # L's own columns (int32 where scipy keeps them so; the kernels read either)
            self._Lp = self.L.indptr.astype(np.int64)
            self._Li = np.ascontiguousarray(self.L.indices)
            self._Lx = np.ascontiguousarray(self.L.data, dtype=np.float64)
            self._E_c = np.ascontiguousarray(self.E)
            self._delta_c = np.ascontiguousarray(self.delta, dtype=np.float64)
            self._rest_c = np.ascontiguousarray(self.rest_edges, dtype=np.float64)

    @property
    def covariance(self) -> sp.csr_matrix:
        """Covariance operator ``M`` (3n × n) of the numpy local step, built on first use.

        ``(M X)[a n + v, b] = μ Σ_{edges e at v} e0[e, a] (X_i − X_j)[e, b]``:
        the one-ring part of the covariance ``A_v[b, a]`` of vertex ``v``.
        """
        if self._covariance is None:
            n, ne = self.n, len(self.E)
            incidence = sp.csr_matrix(
                (np.ones(2 * ne), (self.E.reshape(-1), np.repeat(np.arange(ne), 2))),
                shape=(n, ne),
            )
            self._covariance = ROTATION_REGULARISATION * sp.vstack(
                [incidence @ sp.diags(self.rest_edges[:, a]) @ self.D for a in range(3)],
                format="csr",
            )
        return self._covariance

    # structure-of-arrays copies for the vectorised numpy local step, made on its first
    # use (the compiled one reads delta and rest_edges: at 1M guest vertices 0.10 GB)
    @functools.cached_property
    def _deltaT(self) -> np.ndarray:
        """``δᵀ``, shape (3, n), contiguous."""
        return np.ascontiguousarray(self.delta.T)

    @functools.cached_property
    def _e0T(self) -> np.ndarray:
        """The rest edges transposed, shape (3, e), contiguous."""
        return np.ascontiguousarray(self.rest_edges.T)

    @property
    def row_patterns(self) -> tuple:
        """Matrices with the patterns of the row blocks :attr:`K` stacks, in order.

        ``(L, D, D)`` rotation-aware (``−D``'s pattern is ``D``'s; the stack is
        0.26 GB at 1M guest vertices, which counts and patterns need not make),
        else ``(L,)``.
        """
        if not self.rotation_aware:
            return (self.K,)
        return (self.L, self.D, self.D)

    @property
    def K(self) -> sp.csr_matrix:
        """Stacked operator ``[L; D; −D]`` (rotation-aware) or ``L``, built on first use."""
        if self._K is None:
            self._K = sp.vstack([self.L, self.D, -self.D], format="csr")
        return self._K

    @property
    def soft_rows(self) -> int:
        """Laplacian constraints only, as the paper counts them."""
        return self.n

    def quadratic(self) -> sp.csr_matrix:
        """``w (LᵀL + 2 μ DᵀD)`` (rotation-aware) or ``w LᵀL``, shape (n, n)."""
        Q = self.Lt @ self.L
        if self.rotation_aware:
            Q = Q + (2.0 * ROTATION_REGULARISATION) * (self.Dt @ self.D)
        return sp.csr_matrix(self.weight * Q)

    def covariances(self, X: np.ndarray, LX: np.ndarray) -> np.ndarray:
        """Per-vertex covariances ``A_v`` of the rotation fit, shape (3, 3, n).

        ``A_v = l(p′)_v l(p)_vᵀ + μ Σ_j (p′_v − p′_j)(p_v − p_j)ᵀ``; the
        rotation of vertex ``v`` maximises ``tr(Rᵀ A_v)``.
        """
        n = self.n
        A = np.ascontiguousarray((self.covariance @ X).T).reshape(3, 3, n)
        A += LX.T[:, None, :] * self._deltaT[None, :, :]
        return A

    def rotations(self, X: np.ndarray, LX: np.ndarray, hint: np.ndarray | None = None):
        """Per-vertex rotations, shape (n, 3, 3), minimising the vertex energies at ``X``.

        Parameters
        ----------
        X : ndarray, shape (n, 3)
        LX : ndarray, shape (n, 3)
            ``L X``.
        hint : ndarray, shape (n, 3, 3), optional
            Starting rotations (see :func:`igljoin.rotations.fit_rotations`).
        """
        if hint is not None:
            hint = np.ascontiguousarray(hint.transpose(1, 2, 0))
        R = fit_rotations(self.covariances(X, LX), hint)
        return R.transpose(2, 0, 1)

    def _fit(self, state: LocalState):
        """``L X`` (n, 3) and the rotations (3, 3, n) at ``state.X``, cached in ``state``."""
        cache = state.cache
        if "LX" not in cache:
            cache["LX"] = self.L @ state.X
        if "R" not in cache:
            if state.rotations is not None:
                # fitted already (by the compiled local step)
                R = np.ascontiguousarray(state.rotations.transpose(1, 2, 0))
            else:
                hint = state.hint
                if hint is not None:
                    hint = np.ascontiguousarray(hint.transpose(1, 2, 0))
                R = fit_rotations(self.covariances(state.X, cache["LX"]), hint)
                state.rotations = R.transpose(2, 0, 1)
            cache["R"] = R
        return cache["LX"], cache["R"]

    def _rotated(self, state: LocalState):
        """``R δ`` (3, n) and the rotated rest edges ``R_i e0``, ``R_j e0`` (3, e) each."""
        key = ("rotated", id(self))
        if key not in state.cache:
            _, R = self._fit(state)
            n = self.n
            R9 = R.reshape(9, n)
            Rd = np.einsum("ijn,jn->in", R, self._deltaT)
            e = len(self.E)
            G0 = np.take(R9, self.E[:, 0], axis=1).reshape(3, 3, e)
            a0 = np.einsum("ije,je->ie", G0, self._e0T)
            G1 = np.take(R9, self.E[:, 1], axis=1).reshape(3, 3, e)
            a1 = np.einsum("ije,je->ie", G1, self._e0T)
            state.cache[key] = (Rd, a0, a1)
        return state.cache[key]

    def target(self, state: LocalState) -> np.ndarray:
        if not self.rotation_aware:
            return self.delta
        Rd, a0, a1 = self._rotated(state)
        return np.concatenate([Rd.T, a0.T, -a1.T])

    def local(self, state: LocalState) -> tuple[float, np.ndarray]:
        """Energy and half gradient without forming ``K`` (see :meth:`Term.local`)."""
        w = self.weight
        if not self.rotation_aware:
            LX = state.cache.get("LX")
            if LX is None:
                LX = state.cache["LX"] = self.L @ state.X
            r = LX - self.delta
            return w * float(np.einsum("ij,ij->", r, r)), w * (self.Lt @ r)
        if self.compiled and state.rotations is None:
            return self._local_from_into(state)
        LX, _ = self._fit(state)
        Rd, a0, a1 = self._rotated(state)
        dT = _edge_vectors(state, self.E, self.D, self.compiled).T
        mu = ROTATION_REGULARISATION
        r = LX.T - Rd
        r0 = dT - a0
        r1 = dT - a1
        e = np.einsum("ij,ij->", r, r) + mu * (
            np.einsum("ij,ij->", r0, r0) + np.einsum("ij,ij->", r1, r1)
        )
        r0 += r1
        grad = self.Lt @ r.T
        grad += mu * (self.Dt @ r0.T)
        grad *= w
        return w * float(e), grad

    def local_into(self, state: LocalState, G: np.ndarray) -> float:
        """:meth:`local` adding into ``G`` (see :meth:`Term.local_into`)."""
        if self.rotation_aware and self.compiled and state.rotations is None:
            return self._local_compiled(state, G)
        return super().local_into(state, G)

    def _local_compiled(self, state: LocalState, G: np.ndarray) -> float:
        """:meth:`local` by the compiled kernels, adding into ``G`` (n, 3).

        Sets ``state.rotations``, and leaves ``L X`` and the edge vectors in
        ``state.cache`` for the terms after it (the stretch term's ``D X``).

        Vertices where the warm-started Newton fit does not settle get their
        rotation from libigl's SVD fit, as in :func:`igljoin.rotations.fit_rotations`.
        """
        n = self.n
        hint = state.hint
        if hint is None or hint.shape != (n, 3, 3):
            hint = _NO_ROTATIONS
        LX = np.empty((n, 3))
        A = np.empty((n, 3, 3))
        R = np.empty((n, 3, 3))
        d = np.empty((len(self._E_c), 3))
        mu = ROTATION_REGULARISATION
        e, failed_mask = kernels.shape_local(
            state.X, self._E_c, self._Lp, self._Li, self._Lx, self._delta_c, self._rest_c,
            mu, self.weight, np.ascontiguousarray(hint, dtype=np.float64), LX, A, R, d, G,
        )  # fmt: skip
        failed = np.flatnonzero(failed_mask)
        if failed.size:
            R[failed] = fit_rotations_igl(A[failed].transpose(1, 2, 0)).transpose(2, 0, 1)
            e = kernels.shape_residuals(
                d, self._E_c, self._Lp, self._Li, self._Lx, LX, self._delta_c,
                self._rest_c, mu, self.weight, R, G,
            )  # fmt: skip
        state.rotations = R
        state.cache["LX"] = LX
        state.cache[_edges_key(self.E)] = d
        return float(e)


#: Stand-in for "no rotations" in the compiled kernels, shape (0, 3, 3).
_NO_ROTATIONS = np.zeros((0, 3, 3))


class StretchTerm(Term):
    """Minimum stretching/shrinking ``Σ k_ij ‖d_ij − s_ij‖²`` (Eq. 5–6).

    ``s_ij`` is the current edge direction scaled to the rest length.

    Parameters
    ----------
    V0 : ndarray, shape (n, 3)
    E : ndarray of int64, shape (e, 2)
    stiffness : ndarray, shape (e,)
        ``k_ij`` (already multiplied by the stretch weight).
    compiled : bool
        Compiled local step (default) or the numpy reference path.
    differences : tuple of scipy.sparse.csr_matrix, optional
        ``difference_operators(E, n)`` (its ``K`` and ``Kᵀ``), shared with the
        shape term (made here when not given).
    """

    name = "stretch"

    #: Its target lies on a sphere of rest length: stiff along the edge, free across it.
    #: 0.2 (with the smooth join's 0.5) needed the fewest iterations on the paper's
    #: samples of the values tried (0.1–0.5; docs/benchmarks.md).
    preconditioner_scale = 0.2

    #: A collapsed edge keeps its rest direction turned by its first vertex's rotation.
    reads_rotations = True

    def __init__(self, V0, E, stiffness, compiled=True, differences=None):
        self.E = E
        self.K, self.Kt = differences or difference_operators(E, len(V0))
        self.weights = np.asarray(stiffness, dtype=np.float64)
        self.rest = np.ascontiguousarray(self.K @ V0)
        self.rest_length = np.linalg.norm(self.rest, axis=1)
        self.compiled = bool(compiled)
        if self.compiled:
            self.E = np.ascontiguousarray(E, dtype=np.int64)

    def share_rest(self, edges: np.ndarray) -> bool:
        """Hold ``edges`` as its rest edges ``D V0`` where they are its own to the bit.

        The rotation-aware shape term's rest edges ``V0[E0] − V0[E1]`` are
        (they may differ only in the sign of a zero): one array then serves
        both (at 1M guest vertices 0.07 GB).

        Parameters
        ----------
        edges : ndarray, shape (e, 3)

        Returns
        -------
        bool
            Whether they are held.
        """
        edges = np.asarray(edges)
        same = (
            edges.dtype == np.float64
            and edges.flags.c_contiguous
            and edges.shape == self.rest.shape
            and np.array_equal(edges.view(np.uint64), self.rest.view(np.uint64))
        )
        if same:
            self.rest = edges
        return same

    def applied(self, state: LocalState) -> np.ndarray:
        """Edge vectors ``D X``, shape (e, 3), shared with the shape term."""
        return _edge_vectors(state, self.E, self.K, self.compiled)

    def local_into(self, state: LocalState, G: np.ndarray) -> float:
        """:meth:`local` adding into ``G`` (see :meth:`Term.local_into`)."""
        if not self.compiled:
            return super().local_into(state, G)
        R = _NO_ROTATIONS if state.rotations is None else state.rotations
        d = _edge_vectors(state, self.E, self.K, True)
        e = kernels.stretch_local(d, self.E, self.weights, self.rest_length, self.rest, R, G)
        return float(e)

    def quadratic(self) -> sp.csr_matrix:
        """``Dᵀ diag(k) D``, shape (n, n)."""
        return sp.csr_matrix(self.Kt @ sp.diags(self.weights) @ self.K)

    def target(self, state: LocalState) -> np.ndarray:
        d = self.applied(state)
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        ok = length > 1e-12 * np.maximum(self.rest_length, 1e-300)
        if ok.all():
            return d * (self.rest_length / length)[:, None]
        out = np.where(ok[:, None], d * (self.rest_length / np.where(ok, length, 1.0))[:, None], 0)
        # a collapsed edge keeps its rest direction (rotated, when rotations are known)
        bad = np.flatnonzero(~ok)
        rest = self.rest[bad]
        if state.rotations is not None:
            rest = np.einsum("nij,nj->ni", state.rotations[self.E[bad, 0]], rest)
        out[bad] = rest
        return out

    def local(self, state: LocalState) -> tuple[float, np.ndarray]:
        """Energy and half gradient ``Dᵀ diag(k) (D X − s)`` (see :meth:`Term.local`)."""
        if self.compiled:
            return self._local_from_into(state)
        d = self.applied(state)
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        if not (length > 1e-12 * np.maximum(self.rest_length, 1e-300)).all():
            r = d - self.target(state)
            e = float(np.dot(self.weights, np.einsum("ij,ij->i", r, r)))
            r *= self.weights[:, None]
            return e, self.Kt @ r
        # d − s = d (1 − L0 / |d|), so ‖d − s‖ = | |d| − L0 |
        gap = length - self.rest_length
        e = float(np.dot(self.weights, gap * gap))
        return e, self.Kt @ (d * (self.weights * gap / length)[:, None])


class SmoothJoinTerm(Term):
    """The guest leaves the seam along the host surface continued (Eq. 7).

    Parameters
    ----------
    V0 : ndarray, shape (n, 3)
        Rest positions of the (refined) guest.
    F : ndarray of int64, shape (m, 3)
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order.
    frames : SeamFrames
        Host frames interpolated at each seam vertex's target, shape (s, 3) each.
    weight : float
        ``w_J``.
    mode : {"band", "robust", "paper"}
        ``"band"``: one row per seam vertex, the guest's direction off the
        seam fitted over a band (``fit``), pulled into the half-plane that
        continues the host (``frames``, fitted over the same band) — slivers,
        very short seam edges and zig-zag seams change neither side.
        ``"paper"``: for each seam vertex ``b`` its tangential point ``b_t``
        (the neighbour most parallel to ``n(b) × (b − b₁)``) is pulled to
        ``b′ + w`` with ``w`` the host's outward cross-seam direction at the
        rest length ``‖b − b_t‖`` — a fixed target. ``"robust"``: every edge
        from a seam vertex to a non-seam neighbour is pulled into the
        half-plane that continues the host surface (the host tangent plane,
        on the side away from the host); the target is the projection of the
        current edge onto that half-plane, so no single noisy neighbour or
        length dictates the result.
    tolerance : float or ndarray, shape (s,)
        Robust and band modes: half-angle in radians of a wedge around the
        half-plane within which an edge (a band row) is left alone (0: exact
        tangent continuity). It keeps the join from flattening what is only
        noise of the host. Band mode takes one angle per seam vertex.
    fit : BandFit, optional
        Band mode: the rest guest's band fit along ``seam``
        (:func:`igljoin.bandfit.band_fit`); its rows become ``K``.
    active : ndarray of bool, shape (s,), optional
        Band mode: seam vertices the term acts on (default all); the others
        keep a row of weight 0.
    compiled : bool
        Compiled local step (default) or the numpy reference path.
    """

    name = "smooth"

    def __init__(
        self,
        V0,
        F,
        seam,
        frames: SeamFrames,
        weight=1.0,
        mode="robust",
        tolerance=0.0,
        fit=None,
        active=None,
        compiled=True,
    ):
        n = len(V0)
        self.mode = mode
        if mode == "band":
            self.tolerance = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), len(seam))
            self._init_band(n, frames, weight, fit)
            if active is not None:
                self.weights = np.where(np.asarray(active, dtype=bool), self.weights, 0.0)
            self.compiled = bool(compiled)
            return
        self.tolerance = float(tolerance)
        on_seam = np.zeros(n, dtype=bool)
        on_seam[seam] = True
        E = unique_edges(F)
        seam_pos = np.full(n, -1, dtype=np.int64)
        seam_pos[seam] = np.arange(len(seam))
        # edges from a seam vertex to a free vertex, oriented seam -> free
        cross = on_seam[E[:, 0]] ^ on_seam[E[:, 1]]
        Ec = E[cross]
        Ec = np.where(on_seam[Ec[:, 0]][:, None], Ec, Ec[:, ::-1])
        if mode == "paper":
            Ec = self._tangential_points(V0, F, seam, on_seam, Ec)
        self.pairs = Ec
        which = seam_pos[Ec[:, 0]]
        self.normal = frames.normal[which]
        self.outward = -frames.inward[which]
        rows = np.repeat(np.arange(len(Ec)), 2)
        vals = np.tile([-1.0, 1.0], len(Ec))
        self.K = sp.csr_matrix((vals, (rows, Ec.reshape(-1))), shape=(len(Ec), n))
        self.weights = np.full(len(Ec), float(weight))
        rest_len = np.linalg.norm(V0[Ec[:, 1]] - V0[Ec[:, 0]], axis=1)
        self.fixed_target = self.outward * rest_len[:, None]
        # the robust target is a projection onto a half-plane (stiff across it only);
        # the paper's is fixed, so its Hessian is Kᵀ W K
        self.preconditioner_scale = 1.0 if mode == "paper" else 0.5
        self.compiled = bool(compiled)
        if self.compiled:
            self.pairs = np.ascontiguousarray(self.pairs, dtype=np.int64)
            self.normal = np.ascontiguousarray(self.normal, dtype=np.float64)
            self.outward = np.ascontiguousarray(self.outward, dtype=np.float64)
            self._fixed_c = (
                np.ascontiguousarray(self.fixed_target) if mode == "paper" else np.zeros((0, 3))
            )

    def _init_band(self, n: int, frames: SeamFrames, weight: float, fit) -> None:
        """One row per seam vertex: the guest's band-fitted direction off the seam."""
        if fit is None:
            raise ValueError("mode='band' needs the guest's band fit (fit=BandFit)")
        # c = ∂X/∂v is a unit-free direction; scaled by the band's edge length so that a
        # row weighs like one cross-seam edge of the robust form
        scale = fit.band / BAND_EDGES
        self.K = sp.csr_matrix(fit.weights * scale)
        if self.K.shape[1] != n:
            raise ValueError("the band fit is of another mesh")
        self.band = float(fit.band)
        #: vertex pairs the rows couple (the non-zeros of their block ``Kᵀ W K``)
        self.couplings = band_couplings(self.K)
        self.pairs = None
        self.normal = np.ascontiguousarray(frames.normal, dtype=np.float64)
        self.outward = np.ascontiguousarray(-frames.inward, dtype=np.float64)
        self.weights = np.full(self.K.shape[0], float(weight) * ROWS_PER_BAND_ROW)
        self.preconditioner_scale = 0.5
        # arrays of the compiled local step (igljoin.kernels.band_local): the columns are
        # K's own (int32 where scipy keeps them so; the kernel reads either, and an int64
        # copy held 0.21 GB at 1M guest vertices)
        self._Kp = self.K.indptr.astype(np.int64)
        self._Ki = np.ascontiguousarray(self.K.indices)
        self._Kx = np.ascontiguousarray(self.K.data, dtype=np.float64)
        self._tol_c = np.ascontiguousarray(self.tolerance, dtype=np.float64)

    def check_size(self) -> None:
        """Refuse to form a band block larger than :data:`MAX_BAND_COUPLINGS`.

        Raises
        ------
        OptionsError
            With a ``smooth_band`` that fits.
        """
        if self.mode != "band" or self.couplings <= MAX_BAND_COUPLINGS:
            return
        pairs = self.couplings
        # couplings grow with the square of the vertices under a row (band width⁴)
        narrower = self.band * 0.9 * (MAX_BAND_COUPLINGS / pairs) ** 0.25
        raise OptionsError(
            f"the smooth join's band ({self.band:.3g} mesh units wide) couples about "
            f"{pairs:,.0f} pairs of guest vertices, more than the size guard of "
            f"{MAX_BAND_COUPLINGS:,} (about {12 * pairs / 1e9:.0f} GB per matrix): the "
            f"guest is much finer than the band; give smooth_band={narrower:.3g} or less, "
            "or smooth_mode='robust', or install igljoin[pardiso] (the join then never forms "
            "this block), or raise igljoin.terms.MAX_BAND_COUPLINGS"
        )

    def quadratic(self) -> sp.csr_matrix:
        """``Kᵀ W K``, shape (n, n); band mode refuses one too large (:meth:`check_size`)."""
        self.check_size()
        return super().quadratic()

    def local(self, state: LocalState) -> tuple[float, np.ndarray]:
        """Energy and half gradient (see :meth:`Term.local`), compiled when available."""
        if not self.compiled:
            return super().local(state)
        return self._local_from_into(state)

    def local_into(self, state: LocalState, G: np.ndarray) -> float:
        """:meth:`local` adding into ``G`` (see :meth:`Term.local_into`)."""
        if not self.compiled:
            return super().local_into(state, G)
        if self.mode == "band":
            e = kernels.band_local(
                state.X, self._Kp, self._Ki, self._Kx, self.normal, self.outward,
                self.weights, self._tol_c, G,
            )  # fmt: skip
        else:
            e = kernels.smooth_local(
                state.X, self.pairs, self.normal, self.outward, self.weights, self.tolerance,
                self._fixed_c, G,
            )  # fmt: skip
        return float(e)

    @staticmethod
    def _tangential_points(V0, F, seam, on_seam, Ec):
        """One cross-seam edge per seam vertex: the paper's tangential point."""
        normals, areas = face_normals_areas(V0, F)
        vn = unit(vertex_face_matrix(F, len(V0))[seam] @ (normals * areas[:, None]))
        nxt = np.roll(seam, -1)
        nxt[-1] = seam[-2]  # b₁ is any seam neighbour; this also suits an open curve's end
        t = unit(np.cross(vn, V0[seam] - V0[nxt]))
        seam_pos = np.full(len(V0), -1, dtype=np.int64)
        seam_pos[seam] = np.arange(len(seam))
        which = seam_pos[Ec[:, 0]]
        d = unit(V0[Ec[:, 0]] - V0[Ec[:, 1]])
        score = np.abs(np.einsum("ij,ij->i", d, t[which]))
        order = np.lexsort((-score, which))
        first = np.r_[True, which[order][1:] != which[order][:-1]]
        return Ec[order[first]]

    def target(self, state: LocalState) -> np.ndarray:
        if self.mode == "paper":
            return self.fixed_target
        d = self.applied(state)
        n = self.normal
        z = np.einsum("ij,ij->i", d, n)
        p = d - z[:, None] * n
        # the half-plane continuing the host: an edge pointing back into the host keeps
        # only its component along the seam (a fold-back is not a resting point)
        out = self.outward
        p = p - np.minimum(np.einsum("ij,ij->i", p, out), 0.0)[:, None] * out
        plen = np.linalg.norm(p, axis=1)
        tol = self.tolerance
        if not np.any(tol):
            return p
        # project (plen, z) onto the wedge |z| <= tan(alpha) plen: keep d if inside,
        # else the closest point on the wedge's face (alpha: one angle, or one per row)
        ca, sa = np.cos(tol), np.sin(tol)
        inside = np.abs(z) <= np.tan(tol) * plen
        s = np.maximum(plen * ca + np.abs(z) * sa, 0.0)
        u = p / np.where(plen > 0, plen, 1.0)[:, None]
        face = s[:, None] * (np.reshape(ca, (-1, 1)) * u + (sa * np.sign(z))[:, None] * n)
        return np.where(inside[:, None], p + z[:, None] * n, face)


def band_couplings(K: sp.csr_matrix, samples: int = 64) -> float:
    """Number of vertex pairs the rows of ``K`` couple: the non-zeros of ``Kᵀ K``.

    Counted exactly for the columns of up to ``samples`` vertices evenly spread
    over those any row uses (the union of the supports of the rows through
    each), and scaled to all of them; exact when ``samples`` covers them all.
    Costs one sparse product of ``samples`` columns, not the whole block.

    Parameters
    ----------
    K : scipy.sparse.csr_matrix, shape (r, n)
    samples : int

    Returns
    -------
    float
    """
    pattern = sp.csr_matrix((np.ones(K.nnz), K.indices, K.indptr), shape=K.shape)
    by_vertex = pattern.tocsc()
    used = np.flatnonzero(np.diff(by_vertex.indptr))
    if not used.size:
        return 0.0
    picked = used[
        np.unique(np.linspace(0, used.size - 1, min(used.size, samples)).round()).astype(np.int64)
    ]
    reach = sp.csr_matrix(by_vertex[:, picked].T @ pattern)
    return float(np.diff(reach.indptr).mean()) * used.size
