"""Local/global iteration around one prefactored constrained quadratic solve (§4.5).

The energy ``E(X) = Σ_terms Σ_r w_r ‖(K X)_r − target_r(X)‖²`` with the seam
vertices fixed is minimised by alternating

* a local step: every term recomputes its target from the current ``X``
  (rotations, edge directions, half-plane projections), and
* a global step: with targets fixed the energy is quadratic; its minimiser
  under the hard constraints ``X[b] = bc`` is one back-substitution with
  the factorization of ``Q = Σ Kᵀ W K`` (:mod:`igljoin.linsolve`), made once.

This is the Gauss–Newton-like scheme the paper refers to; each step cannot
increase the energy.

Every target is the closest point of ``K X`` in a fixed set (rotated rest
coordinates, spheres of rest length, a half-plane or wedge), so ``E`` is a
sum of squared distances to fixed sets and its gradient is
``∇E = 2 (Q X − Σ Kᵀ W target(X))``: the global step is a gradient step
preconditioned by ``Q``. The accelerated iteration uses exactly that: a
limited-memory BFGS method whose initial inverse Hessian is a factored
quadratic form — with a backtracking line search that only accepts steps
that decrease the energy (Liu, Bouaziz and Kavan, "Quasi-Newton methods for
real-time simulation of hyperelastic materials", ACM TOG 2017). When no
step along the quasi-Newton direction is acceptable the plain local/global
step is taken, which always is.

The initial Hessian is not ``Q`` itself but ``P = Σ c_t K_tᵀ W_t K_t``.
A term whose target is a projection (the stretch term's sphere of rest
length, the smooth join's half-plane) has the stiffness ``Kᵀ W K`` only
across its set and none along it, so ``Q`` overstates how stiff the energy
is in exactly the directions the iteration is slow in (bending, turning
edges). Scaling those terms down in ``P`` (``c_t`` =
:attr:`igljoin.terms.Term.preconditioner_scale`) gives a model closer to
the true Hessian: on the paper's samples it cuts the iterations to
convergence by about 40 % (docs/benchmarks.md), to the same minimum.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from . import kernels
from .errors import SolveError
from .linsolve import AugmentedQuadratic, FixedQuadratic, available_backends
from .terms import LocalState, SmoothJoinTerm, Term

__all__ = ["LocalGlobalSolver", "IterationResult", "QuasiNewtonMemory", "AUGMENT_FROM_COUPLINGS"]

#: Vertex pairs coupled by the band smooth-join rows (:func:`igljoin.terms.band_couplings`,
#: the non-zeros of their block ``Kᵀ W K``) from which the solver keeps that block out
#: of ``P`` and ``Q`` and factors the augmented system instead
#: (:class:`igljoin.linsolve.AugmentedQuadratic`), when MKL Pardiso is installed and
#: ``linear_solver`` is ``"auto"`` or ``"pardiso"``. Measured on the partial patch
#: (whole joins, alternated, 2 shared cores; the same iterations): 5.7e5 pairs (10k
#: guest vertices) 1.43 s against 1.30 s with the block formed (Pardiso's indefinite
#: back-solve, 4.6 ms, is twice cholespy's); 1.8e6 (20k) 3.6 s against 4.2–4.9 s;
#: 3.7e6 (30k) 6.2 s against 9.0 s; 3.5e7 (100k) 34 s against 59 s.
AUGMENT_FROM_COUPLINGS = 1_000_000

# iterations over which the relative energy change is measured for convergence
_WINDOW = 5

# The decrease still to come, extrapolated from the last ``_RATE_DECREASES`` decreases
# (see _remaining_decrease), also stops a run once it is below ``_RATE_SHARE`` times the
# tolerance. On a steady tail of ~10 iterations a decade (ratio 0.8) the window's test
# stops where that estimate is about half the tolerance (4 δ against 8.2 δ), so the share
# of one half asks the same accuracy there; the estimate reads only the last four
# energies (from the fourth iteration on), not the window's six, so a warm start's first
# large drop does not hold it. Only steps taken whole count (see _StoppingTest): a
# shortened step measures the line search, not the rate. Measured against
# the window alone (gaps relative to a run to 1e-13): cold solves of the paper samples'
# slider targets 5,397 -> 5,357 iterations, of 47 real-mesh cuts' 8,973 -> 8,540, the
# largest gaps the same (6.6e-7, 1.8e-7); slider re-solves along paths 718 -> 664 and
# 4,945 -> 4,410, largest gaps 3.8e-7 -> 3.6e-7 and 1.8e-7 -> 3.0e-7.
_RATE_DECREASES = 3
_RATE_SHARE = 0.5

# Armijo sufficient-decrease constant of the line search (any value <= 1/2 accepts
# the plain local/global step, which always decreases the energy by at least
# its model's prediction)
_ARMIJO = 1e-4

# line-search halvings before the quasi-Newton memory is dropped and the plain
# step taken instead
_MAX_BACKTRACKS = 6


@dataclass
class IterationResult:
    """Outcome of :meth:`LocalGlobalSolver.run`.

    Attributes
    ----------
    X : ndarray, shape (n, 3)
        Final positions.
    energy : list of float
        Energy after the initial guess and after each iteration.
    iterations : int
    converged : bool
    reason : str
        ``"tolerance"``, ``"max_iterations"`` or ``"time_limit"``.
    timings : dict
        Seconds spent in ``local`` steps (targets, rotations, energy,
        right-hand sides) and ``solve`` steps (back-substitutions).
    stats : dict
        ``local_steps`` (local steps evaluated, including rejected line-search
        trials), ``back_solves``, ``rejected`` (line-search trials that did not
        decrease the energy enough), ``restarts`` (quasi-Newton memory
        dropped) and ``model_builds`` (builds and rebuilds of a ``model``
        during the run).
    memory : QuasiNewtonMemory or None
        The quasi-Newton pairs held at the end (``None`` for the plain
        iteration): a later run of the same solver may start from them
        (``run(memory=...)``).
    rotations : ndarray, shape (n, 3, 3), or None
        The rotations fitted by the last local step (at ``X``; ``None`` when no
        term fits rotations): a later run from near ``X`` may start its first
        rotation fit from them (``run(rotations=...)``).
    """

    X: np.ndarray
    energy: list = field(default_factory=list)
    iterations: int = 0
    converged: bool = False
    reason: str = ""
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    memory: QuasiNewtonMemory | None = None
    rotations: np.ndarray | None = None


class LocalGlobalSolver:
    """Assemble and factor the quadratic form once; iterate many times.

    Parameters
    ----------
    terms : list of Term
    n : int
        Number of vertices.
    fixed : ndarray of int64, shape (b,)
        Vertices held at prescribed positions.
    linear_solver : {"auto", "igl", "cholespy"}
        Backend of the factorization (see :mod:`igljoin.linsolve`).

    Attributes
    ----------
    Q : scipy.sparse.csr_matrix, shape (n, n)
        ``Σ Kᵀ W K``.
    P : scipy.sparse.csr_matrix, shape (n, n)
        The quasi-Newton preconditioner ``Σ c_t K_tᵀ W_t K_t`` with each
        term's :attr:`~igljoin.terms.Term.preconditioner_scale` ``c_t``; it
        is what :attr:`factor` factors.
    wide : SmoothJoinTerm or None
        The band smooth-join term whose block ``Kᵀ W K`` is kept out of the
        matrices (its rows couple :data:`AUGMENT_FROM_COUPLINGS` vertex pairs or
        more and Pardiso is there): :attr:`factor` is then an
        :class:`~igljoin.linsolve.AugmentedQuadratic`, and ``Q`` and ``P``
        are formed only when read (the other terms' sums are not kept either:
        each is made where it is used). ``None``: both formed, ``factor`` a
        :class:`~igljoin.linsolve.FixedQuadratic`.
    factor : FixedQuadratic or AugmentedQuadratic
        The factored ``P`` with the fixed rows.
    backend : str
        The linear solver used.
    factor_seconds : float
        Time to assemble and factor ``P``.
    factorizations : int
        Factorizations made (``P``, and ``Q`` once the plain iteration needs it).
    """

    def __init__(self, terms: list[Term], n: int, fixed: np.ndarray, linear_solver: str = "auto"):
        t0 = time.perf_counter()
        self.terms = terms
        self.n = n
        self.fixed = np.asarray(fixed, dtype=np.int64)
        self.linear_solver = linear_solver
        self.wide = _wide_term(terms, linear_solver)
        self._Q = self._P = None
        self._stiffness_bound: float | None = None
        # with the band block kept apart: the other terms' part of that bound, from P's
        # rest at set-up (None where the scales allow none)
        self._rest_bound: float | None = None
        if self.wide is None:
            same = all(term.preconditioner_scale == 1.0 for term in terms)
            self._Q, P = _summed(terms, n, scaled=not same)
            self._P = self._Q if same else P
            self.factor = FixedQuadratic(self._P, self.fixed, linear_solver)
            self._plain_factor = self.factor if self._P is self._Q else None
        else:
            # the wide term's block stays out of every matrix: the augmented system is
            # factored from the other terms' sum with their scales (P's rest), let go once
            # factored; their plain sum (Q's rest) is not made here. Each is made again
            # where it is used (_rest)
            w = self.wide
            scaled_rest = self._rest(scaled=True)
            self._rest_bound = _rest_stiffness_bound(terms, w, scaled_rest)
            self.factor = AugmentedQuadratic(
                scaled_rest, w.K, w.weights, w.preconditioner_scale, self.fixed
            )
            del scaled_rest
            self._plain_factor = None
        self.factorizations = 1
        self.backend = self.factor.backend
        self.free = self.factor.free
        self.factor_seconds = time.perf_counter() - t0

    @property
    def Q(self) -> sp.csr_matrix:
        """``Σ Kᵀ W K``, shape (n, n); with a wide term formed only on first use."""
        if self._Q is None:
            band = self.wide.quadratic()  # refused first where it is too large to form
            self._Q = sp.csr_matrix(self._rest(scaled=False) + band)
        return self._Q

    @property
    def P(self) -> sp.csr_matrix:
        """``Σ c_t K_tᵀ W_t K_t``, shape (n, n); with a wide term formed only on first use."""
        if self._P is None:
            w = self.wide
            band = w.preconditioner_scale * w.quadratic()
            self._P = sp.csr_matrix(self._rest(scaled=True) + band)
        return self._P

    def _rest(self, scaled: bool) -> sp.csr_matrix:
        """The terms other than :attr:`wide` summed (:func:`_summed`), made on each use.

        ``Σ K_tᵀ W_t K_t`` (the plain step's, ``Q``'s and the energy floor's) or,
        ``scaled``, ``Σ c_t K_tᵀ W_t K_t`` (``P``'s), shape (n, n). Not kept: the
        factorization holds its own copy of the scaled one's free rows, and the
        plain one is read by the energy floor (only of a run whose energy falls
        below :meth:`stiffness_bound`'s bound of it: a guest already in place) and
        by the plain factorization (once); on the 1M-vertex tube each is
        0.36 GB. Made again it costs 0.03 s on a 30k-vertex patch guest and
        0.12 s at 100k.
        """
        others = [term for term in self.terms if term is not self.wide]
        Q, P = _summed(others, self.n, plain=not scaled, scaled=scaled)
        return P if scaled else Q

    def plain_factor(self) -> FixedQuadratic | AugmentedQuadratic:
        """The factored ``Q`` itself (the plain global step), made on first use."""
        if self._plain_factor is None:
            if self.wide is None:
                self._plain_factor = FixedQuadratic(self.Q, self.fixed, self.linear_solver)
            else:
                w = self.wide
                self._plain_factor = AugmentedQuadratic(
                    self._rest(scaled=False), w.K, w.weights, 1.0, self.fixed
                )
            self.factorizations += 1
        return self._plain_factor

    # -- building blocks ----------------------------------------------------------------

    def local(self, X: np.ndarray, hint: np.ndarray | None = None):
        """Local step at ``X`` (n, 3): ``(state, energy, G)``.

        ``G = Σ Kᵀ W (K X − target(X))`` (n, 3) is half the gradient of the
        energy. ``hint`` (n, 3, 3) are rotations of a nearby iterate to start
        the rotation fit from.
        """
        state = LocalState(X, hint=hint)
        e = 0.0
        rhs = np.zeros((self.n, 3))
        for term in self.terms:
            e += term.local_into(state, rhs)
        if not math.isfinite(e):
            raise SolveError(
                "the solve produced non-finite positions; the guest has degenerate or "
                "collapsed faces — repair it with igljoin.clean and retry"
            )
        return state, e, rhs

    def energy(self, X: np.ndarray) -> float:
        """``E(X)`` for positions of shape (n, 3)."""
        return self.local(X)[1]

    def extend(self, displacement: np.ndarray) -> np.ndarray:
        """Smooth extension of a displacement of the fixed vertices to all vertices.

        Solves ``P u = 0`` on the free vertices with ``u[fixed] = displacement``
        (shape (b, 3)); reuses the factorization. Returns shape (n, 3).
        """
        return self.factor.solve(np.zeros((self.n, 3)), displacement)

    def bump(self) -> np.ndarray:
        """Response to a unit load with the fixed vertices at zero: ``P φ = 1``, shape (n,)."""
        out = self.factor.solve(np.ones((self.n, 1)), np.zeros((len(self.fixed), 1)))
        return out[:, 0]

    def stiffness_bound(self) -> float | None:
        """An upper bound of ``Q``'s largest eigenvalue, made once (on first use).

        ``Q``'s largest absolute row sum. With the band block kept apart, without
        forming ``Q = Q_rest + Kᵀ W K``: the other terms' part made at set-up
        (:func:`_rest_stiffness_bound`) plus a bound of the band rows' block's
        (Weyl), the largest of its rows' absolute sums bounded from ``K``
        (:func:`igljoin.kernels.gram_row_bound`, Gershgorin); ``None`` if the
        preconditioner's scales do not allow the first.
        """
        if self._stiffness_bound is None and self.wide is None:
            # read from the stored entries (duplicates counted apart: a larger bound, still
            # one); scipy's abs() would sort Q's indices in place, and with them the
            # order its products sum in
            Q = self.Q
            rows = np.repeat(np.arange(Q.shape[0]), np.diff(Q.indptr))
            sums = np.bincount(rows, weights=np.abs(Q.data), minlength=Q.shape[0])
            self._stiffness_bound = float(sums.max(initial=0.0))
        elif self._stiffness_bound is None and self._rest_bound is not None:
            w = self.wide
            K = w.K  # CSR, as the band term makes it
            band = kernels.gram_row_bound(K.indptr, K.indices, K.data, w.weights, K.shape[1])
            self._stiffness_bound = self._rest_bound + float(band)
        return self._stiffness_bound

    def energy_floor(self, X: np.ndarray, tolerance: float) -> float:
        """Energy below which ``X``'s neighbourhood counts as a zero-energy minimum.

        ``E_ref = Σ_terms Σ_r w_r ‖(K (X − x̄))_r‖² = tr(X̄ᵀ Q X̄)`` is the
        energy the terms would have if every quantity they measure (edge
        vectors, Laplacian vectors, cross-seam directions) were missing —
        the squared size of what the energy compares, independent of where
        the guest lies and of its units. The floor ``tolerance² × E_ref``
        is the energy whose residuals are, in the root mean square, a
        fraction ``tolerance`` of those quantities: at or below it the
        relative test has nothing left to resolve (an energy of rounding
        noise, about 1e-30 of ``E_ref`` for a guest at its rest shape,
        changes by its own size from one iteration to the next), and what
        it could still gain is below ``tolerance²`` of the energy scale.
        A real deformation (strains of 1e-4 and more) has energies many
        orders above it, so the floor never stops a join that is still
        moving.

        Parameters
        ----------
        X : ndarray, shape (n, 3)
            Positions of the scale (e.g. the initial guess).
        tolerance : float

        Returns
        -------
        float
        """
        Xc = np.asarray(X, dtype=np.float64) - np.mean(X, axis=0)
        if self.wide is None:
            e_ref = float(np.einsum("ij,ij->", Xc, self.Q @ Xc))
        else:
            KX = self.wide.K @ Xc
            e_ref = float(np.einsum("ij,ij->", Xc, self._rest(scaled=False) @ Xc)) + float(
                np.dot(self.wide.weights, np.einsum("ij,ij->i", KX, KX))
            )
        return tolerance * tolerance * max(e_ref, 0.0)

    # -- the iteration ------------------------------------------------------------------

    def run(
        self,
        X0: np.ndarray,
        bc: np.ndarray,
        *,
        max_iterations: int = 200,
        tolerance: float = 1e-5,
        time_limit: float | None = None,
        scale: float = 1.0,
        acceleration: int = 5,
        callback=None,
        model=None,
        memory: QuasiNewtonMemory | None = None,
        rotations: np.ndarray | None = None,
    ) -> IterationResult:
        """Iterate from ``X0`` (shape (n, 3)) until the iterates settle.

        With ``acceleration == 0`` every iteration is one local step
        (targets) and one global step (back-substitution). With
        ``acceleration = m > 0`` the global step is replaced by a limited-
        memory BFGS step over the last ``m`` iterates (initial inverse
        Hessian: the factored preconditioner ``P``), accepted only if it
        lowers the energy enough (Armijo); otherwise the step is shortened
        and, after a few failures, the plain local/global step is taken. Either way the
        energy decreases at every iteration.

        Parameters
        ----------
        X0 : ndarray, shape (n, 3)
            Initial guess; its fixed rows are replaced by ``bc``.
        bc : ndarray, shape (b, 3)
            Positions of the fixed vertices.
        max_iterations : int
        tolerance : float
            Converged when the last iteration moved no vertex by more than
            ``sqrt(tolerance) × scale`` and either the energy fell by less
            than ``tolerance`` times its value over the last five iterations,
            or the decrease still to come, extrapolated from the last three
            steps (each taken whole) at the slowest of their two ratios, is
            below half that (:func:`_remaining_decrease`), or the energy is at
            its floor, ``tolerance² × E_ref`` (see :meth:`energy_floor`): a
            guest already at a minimum of zero energy (joined back where it
            was cut from) stops at once.
        time_limit : float, optional
            Wall-clock seconds after which the current iterate is returned
            (``converged=False``, ``reason="time_limit"``).
        scale : float
            Length scale of the step criterion (e.g. the mean edge length).
        acceleration : int
            Quasi-Newton history length; 0 for the plain local/global iteration.
        callback : callable, optional
            Called as ``callback(iteration, energy)`` after every iteration.
        model : optional
            A replacement of the initial inverse Hessian ``P_ff⁻¹`` of the
            quasi-Newton steps (e.g. :class:`igljoin.newton.NewtonModel` or
            :class:`igljoin.twolevel.TwoLevelModel`):
            an object with ``refresh(state, iteration) -> bool`` (called
            before every iteration with the current local state; ``True``
            when the quasi-Newton memory must be dropped),
            ``solve_free(v)`` for ``v`` of shape (n_free, 3) and
            ``factorizations`` (its builds so far: those of this run are
            ``stats["model_builds"]``). The plain
            fallback step stays ``Q``'s.
        memory : QuasiNewtonMemory, optional
            Quasi-Newton pairs to start with (``IterationResult.memory`` of an
            earlier run of this solver, e.g. the one whose result ``X0`` was
            predicted from): the first step then already knows the curvature
            they measured. Copied, not changed; ignored unless it holds pairs
            of this run's ``acceleration`` and size.
        rotations : ndarray, shape (n, 3, 3), optional
            Rotations to start the first local step's rotation fit from
            (e.g. ``IterationResult.rotations`` of the run whose result ``X0``
            was predicted from, turned as it was turned); without them the fit
            starts each vertex from its neighbour's rotation. Either start ends
            at the same rotations to within the fit's tolerance; from a near one
            the fit takes fewer steps.

        Returns
        -------
        IterationResult
        """
        start = time.perf_counter()
        clock = {"local": 0.0, "solve": 0.0, "model": 0.0}
        stats = {
            "local_steps": 0,
            "back_solves": 0,
            "rejected": 0,
            "restarts": 0,
            "model_builds": 0,
        }
        builds_before = 0 if model is None else model.factorizations
        free, fixed = self.free, self.fixed
        # (b, 3) rows for the compiled scatter (broadcast as ``X[fixed] = bc`` would)
        bc = np.ascontiguousarray(
            np.broadcast_to(np.asarray(bc, dtype=np.float64), (len(fixed), 3))
        )

        n = self.n

        def local(x, hint):
            t0 = time.perf_counter()
            X = kernels.join_rows(n, free, x, fixed, bc)
            state, e, G = self.local(X, hint)
            clock["local"] += time.perf_counter() - t0
            stats["local_steps"] += 1
            return state, e, kernels.take_rows(G, free)

        def back_solve(v, plain=False):
            # the quasi-Newton steps use the preconditioner P; the plain global step is Q's
            t0 = time.perf_counter()
            if plain or acceleration == 0:
                factor = self.plain_factor()
            else:
                factor = self.factor if model is None else model
            out = factor.solve_free(v)
            clock["solve"] += time.perf_counter() - t0
            stats["back_solves"] += 1
            return out

        X = np.array(X0, dtype=np.float64)
        X[fixed] = bc
        result = IterationResult(X=X)
        if not free.size:
            result.energy = [self.local(X)[1]]
            result.converged, result.reason = True, "tolerance"
            result.timings, result.stats = clock, stats
            return result

        x = np.ascontiguousarray(X[free])
        # g: half the gradient of E on the free rows
        state, e, g = local(x, rotations)
        energy = [e]
        if memory is not None and memory.fits(acceleration, g.shape):
            memory = memory.copy()
        else:
            memory = QuasiNewtonMemory(acceleration, g.shape)
        converged = _StoppingTest(self, X, tolerance, scale)
        for it in range(1, max_iterations + 1):
            hint = state.rotations
            whole = True
            if model is not None and acceleration > 0:
                t0 = time.perf_counter()
                if model.refresh(state, it):
                    memory.clear()
                    whole = False
                clock["model"] += time.perf_counter() - t0
            if acceleration > 0 and memory.size:
                d = -memory.apply(g, back_solve)
                gd = kernels.dot(g, d)
                if not gd < 0.0:
                    memory.clear()
                    stats["restarts"] += 1
                    whole = False
                    d = -back_solve(g)
                    gd = kernels.dot(g, d)
            else:
                # the plain global step
                d = -back_solve(g)
                gd = kernels.dot(g, d)
            t = 1.0
            for _ in range(_MAX_BACKTRACKS + 1):
                x_new = kernels.step(x, t, d)
                state_new, e_new, g_new = local(x_new, hint)
                # Armijo on E with directional derivative 2 gᵀd
                if e_new <= e + _ARMIJO * t * 2.0 * gd or acceleration == 0:
                    break
                stats["rejected"] += 1
                whole = False
                # backtrack with the minimiser of the quadratic through e, slope and e_new
                denom = e_new - e - 2.0 * gd * t
                t_q = -gd * t * t / denom if denom > 0 else 0.5 * t
                t = min(max(t_q, 0.1 * t), 0.5 * t)
            else:
                # no acceptable step along d: drop the memory, take the plain local/global
                # step (Q's), which always lowers the energy
                memory.clear()
                stats["restarts"] += 1
                t = 1.0
                d = -back_solve(g, plain=True)
                x_new = kernels.step(x, 1.0, d)
                state_new, e_new, g_new = local(x_new, hint)
            if acceleration > 0:
                memory.push(x_new, x, g_new, g)
            move = t * kernels.abs_max(d)
            x, e, g, state = x_new, e_new, g_new, state_new
            energy.append(e)
            result.iterations = it
            if callback is not None:
                callback(it, e)
            if converged(energy, move, whole):
                result.converged, result.reason = True, "tolerance"
                break
            if time_limit is not None and time.perf_counter() - start > time_limit:
                result.reason = "time_limit"
                break
        else:
            result.reason = "max_iterations"
        result.X = kernels.join_rows(self.n, free, x, fixed, bc)
        result.energy = energy
        result.timings = dict(clock)
        if model is not None:
            stats["model_builds"] = model.factorizations - builds_before
        result.stats = stats
        result.memory = memory if acceleration > 0 else None
        result.rotations = state.rotations
        return result


def _remaining_decrease(energy: list) -> float:
    """The energy decrease still to come if the run kept its slowest recent rate.

    With ``δ`` the last :data:`_RATE_DECREASES` decreases of ``energy`` (each
    positive) and ``ρ`` the largest ratio of one to the one before, a run that
    went on at that rate would lower the energy by ``δ_last ρ / (1 − ρ)`` more
    (a geometric tail). Infinite before the fourth iteration (so the first
    decrease, the start's own drop, never counts: a warm start's is large),
    and while a decrease is not positive or the decreases do not shrink
    (``ρ ≥ 1``).

    Parameters
    ----------
    energy : list of float
        Energy after the initial guess and after each iteration so far.

    Returns
    -------
    float
    """
    k = _RATE_DECREASES
    if len(energy) < k + 2:
        return math.inf
    tail = energy[-k - 1 :]
    decreases = [a - b for a, b in zip(tail[:-1], tail[1:])]
    if min(decreases) <= 0.0:
        return math.inf
    rate = max(b / a for a, b in zip(decreases[:-1], decreases[1:]))
    if rate >= 1.0:
        return math.inf
    return decreases[-1] * rate / (1.0 - rate)


def _summed(
    terms: list[Term], n: int, *, plain: bool = True, scaled: bool = False
) -> tuple[sp.csr_matrix | None, sp.csr_matrix | None]:
    """``Σ K_tᵀ W_t K_t`` and ``Σ c_t K_tᵀ W_t K_t`` over ``terms``, each block added as it is made.

    The sums of :meth:`~igljoin.terms.Term.quadratic` (scaled by
    :attr:`~igljoin.terms.Term.preconditioner_scale` ``c_t``) in the order of
    ``terms``, from an empty ``n × n`` matrix: the floats and the layout of
    ``sum(blocks, sp.csr_matrix((n, n)))``. Only one term's block is held at a
    time, not a list of them (and of their scaled copies) while the sums are
    factored: on the 1M-vertex tube those lists held 0.72 GB through the
    factorization, the peak of its set-up.

    Parameters
    ----------
    terms : list of Term
    n : int
        Number of vertices.
    plain, scaled : bool
        Make the plain sum, the scaled one.

    Returns
    -------
    Q, P : scipy.sparse.csr_matrix, shape (n, n), or None
        The plain and the scaled sums (``None`` where not asked for).
    """
    zero = sp.csr_matrix((n, n))
    Q = P = zero
    for term in terms:
        block = term.quadratic()
        if plain:
            Q = Q + block
        if scaled:
            P = P + term.preconditioner_scale * block
    return (sp.csr_matrix(Q) if plain else None), (sp.csr_matrix(P) if scaled else None)


def _rest_stiffness_bound(
    terms: list[Term], wide: Term, scaled_rest: sp.csr_matrix
) -> float | None:
    """An upper bound of the largest eigenvalue of the terms' sum other than ``wide``'s.

    ``Q_rest = Σ K_tᵀ W_t K_t``, a sum of positive semidefinite blocks, is
    below their scaled sum ``P_rest`` (``scaled_rest``) divided by the smallest
    scale ``c_t``, so its largest eigenvalue is at most ``P_rest``'s largest
    absolute row sum over ``c_t``: read at set-up from the matrix factored
    there, so that the energy floor's test rarely makes ``Q_rest`` again
    (0.12 s a run of a 100k-vertex guest; see
    :meth:`LocalGlobalSolver.stiffness_bound`).

    Parameters
    ----------
    terms : list of Term
        The join's terms, ``wide`` among them.
    wide : Term
        The term kept apart.
    scaled_rest : scipy.sparse.csr_matrix, shape (n, n)
        ``Σ c_t K_tᵀ W_t K_t`` over the other terms.

    Returns
    -------
    float or None
        ``None`` where a scale is not positive (no such bound).
    """
    smallest = min((t.preconditioner_scale for t in terms if t is not wide), default=1.0)
    if not smallest > 0.0:
        return None
    # compiled: no (nnz,) temporaries at the set-up of a 1M-vertex guest
    rest = kernels.abs_row_sums(scaled_rest.indptr, scaled_rest.data).max(initial=0.0)
    return float(rest / smallest)


def _wide_term(terms: list[Term], linear_solver: str) -> Term | None:
    """The band smooth-join term to keep out of the matrices, or ``None``.

    One whose rows couple :data:`AUGMENT_FROM_COUPLINGS` vertex pairs or more,
    when the augmented system can be factored (Pardiso installed and allowed).
    """
    if linear_solver not in ("auto", "pardiso"):
        return None
    wide = [
        t
        for t in terms
        if isinstance(t, SmoothJoinTerm)
        and t.mode == "band"
        and t.couplings >= AUGMENT_FROM_COUPLINGS
    ]
    if len(wide) != 1 or "pardiso" not in available_backends():
        return None
    return wide[0]


class _StoppingTest:
    """Whether a run has converged, asked after every iteration (see :meth:`LocalGlobalSolver.run`).

    The last iteration moved no vertex by more than ``sqrt(tolerance) × scale``
    and one of: the energy fell by less than ``tolerance`` times its value over
    the last :data:`_WINDOW` iterations; the decrease still to come
    (:func:`_remaining_decrease`) is below :data:`_RATE_SHARE` times that,
    measured over steps each taken whole (a shortened step, a restart or a
    rebuilt model measures the line search, not the iteration's rate); the
    energy is at its floor (:class:`_FloorTest`).

    Parameters
    ----------
    solver : LocalGlobalSolver
    X : ndarray, shape (n, 3)
        The run's start (the floor's scale).
    tolerance, scale : float
        As :meth:`LocalGlobalSolver.run`'s.
    """

    def __init__(self, solver: LocalGlobalSolver, X: np.ndarray, tolerance: float, scale: float):
        self.tolerance = tolerance
        self.step_tolerance = math.sqrt(tolerance) * scale
        # the floor, made only when it decides
        self.floor = _FloorTest(solver, X, tolerance)
        self.whole_steps = 0

    def __call__(self, energy: list, move: float, whole: bool) -> bool:
        """After an iteration: converged?

        Parameters
        ----------
        energy : list of float
            Energy after the initial guess and after each iteration so far.
        move : float
            The last iteration's largest coordinate change.
        whole : bool
            The last iteration took its first trial step whole, with the
            quasi-Newton memory and model it started with.

        Returns
        -------
        bool
        """
        self.whole_steps = self.whole_steps + 1 if whole else 0
        if move > self.step_tolerance:
            return False
        e, tolerance = energy[-1], self.tolerance
        window = energy[max(0, len(energy) - 1 - _WINDOW)] - e
        return (
            (len(energy) > 2 and abs(window) <= tolerance * max(e, 1e-300))
            or (
                self.whole_steps >= _RATE_DECREASES
                and _remaining_decrease(energy) <= _RATE_SHARE * tolerance * e
            )
            or self.floor.reached(e)
        )


class _FloorTest:
    """``e <= solver.energy_floor(X, tolerance)``, with the floor made only when it may hold.

    The floor is ``tolerance² tr(X̄ᵀ Q X̄)``, at most ``tolerance² λ ‖X̄‖²`` with
    ``λ`` :meth:`LocalGlobalSolver.stiffness_bound`; an energy above that bound
    (every real join's, by orders) is above the floor without making it (a
    sparse product with ``Q``), and the answer is the same. The bound too is
    made on the first question (a run asks only once its steps are small);
    with the band block kept apart its other terms' part is made at set-up,
    from the matrix factored there (:func:`_rest_stiffness_bound`).
    """

    def __init__(self, solver: LocalGlobalSolver, X: np.ndarray, tolerance: float):
        self.solver, self.X, self.tolerance = solver, X, tolerance
        self.floor: float | None = None

    @cached_property
    def bound(self) -> float:
        """An upper bound of the floor (``inf`` where ``Q``'s stiffness bound is not known)."""
        stiffness = self.solver.stiffness_bound()
        if stiffness is None:
            return math.inf
        X, tolerance = self.X, self.tolerance
        Xc = X - np.mean(X, axis=0)
        # 1e-6: far above the rounding of either sum, so the bound stays a bound
        return (1.0 + 1e-6) * tolerance * tolerance * stiffness * float(np.vdot(Xc, Xc))

    def reached(self, e: float) -> bool:
        """The energy ``e`` is at or below the floor."""
        if e > self.bound:
            return False
        if self.floor is None:
            self.floor = self.solver.energy_floor(self.X, self.tolerance)
        return e <= self.floor


class QuasiNewtonMemory:
    """The last ``m`` quasi-Newton pairs ``(s, y)`` in ring buffers.

    Parameters
    ----------
    m : int
        Pairs kept (0: none).
    shape : tuple
        Shape of one iterate, e.g. ``(n_free, 3)``.

    Notes
    -----
    The buffers hold ``m + 1`` rows: a new pair is written into a free row
    and only then accepted or refused, so a refused pair never overwrites
    the oldest one kept.
    """

    def __init__(self, m: int, shape: tuple):
        N = int(np.prod(shape))
        rows = m + 1 if m > 0 else 0
        self.m = m
        self.S = np.empty((rows, N))
        self.Y = np.empty((rows, N))
        self.rho = np.empty(rows)
        self.alpha = np.empty(rows)
        self.order: list[int] = []  # slots, oldest first
        self.unused = list(range(rows))

    def fits(self, m: int, shape: tuple) -> bool:
        """It holds pairs for a run with ``m`` pairs and iterates of ``shape``."""
        return self.m == m and self.S.shape[1] == int(np.prod(shape))

    def copy(self) -> QuasiNewtonMemory:
        """An independent copy: every array and list attribute copied (a shallow copy
        of each, not ``copy.deepcopy``'s walk: 0.05 against 0.25 ms on a paper-sized guest)."""
        other = QuasiNewtonMemory.__new__(QuasiNewtonMemory)
        other.__dict__ = {
            k: v.copy() if isinstance(v, (np.ndarray, list)) else v for k, v in vars(self).items()
        }
        return other

    @property
    def size(self) -> int:
        """Pairs held."""
        return len(self.order)

    def clear(self) -> None:
        """Forget every pair."""
        self.order.clear()
        self.unused = list(range(len(self.rho)))

    def push(self, x_new: np.ndarray, x: np.ndarray, g_new: np.ndarray, g: np.ndarray) -> None:
        """Keep the pair ``s = x_new − x``, ``y = g_new − g`` if its curvature ``sᵀy`` is
        positive (else BFGS would break); all four are C-contiguous, shaped like an iterate."""
        slot = self.unused[-1]
        sy, yy = kernels.lbfgs_pair(self.S, self.Y, slot, x_new, x, g_new, g)
        if not (sy > 1e-12 * yy and sy > 0.0):
            return
        self.unused.pop()
        self.rho[slot] = 1.0 / sy
        self.order.append(slot)
        if len(self.order) > self.m:
            self.unused.append(self.order.pop(0))

    def apply(self, g: np.ndarray, back_solve) -> np.ndarray:
        """The inverse-Hessian model applied to ``g`` (L-BFGS two-loop recursion).

        The initial inverse Hessian is ``P_ff⁻¹`` (``back_solve``, one
        back-substitution). Returns an array shaped like ``g``.
        """
        order = np.asarray(self.order, dtype=np.int64)
        q = np.array(g, dtype=np.float64).reshape(-1)
        kernels.lbfgs_first_loop(q, self.S, self.Y, self.rho, order, self.alpha)
        z = np.ascontiguousarray(back_solve(q.reshape(g.shape))).reshape(-1)
        kernels.lbfgs_second_loop(z, self.S, self.Y, self.rho, order, self.alpha)
        return z.reshape(g.shape)
