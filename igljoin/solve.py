"""Local/global iteration around one prefactored constrained quadratic solve (§4.5).

The energy ``Σ_terms Σ_r w_r ‖(K X)_r − target_r(X)‖²`` with the seam
vertices fixed is minimised by alternating

* a local step: every term recomputes its target from the current ``X``
  (rotations, edge directions, half-plane projections), and
* a global step: with targets fixed the energy is quadratic; its minimiser
  under the hard constraints ``X[b] = bc`` is one back-substitution with
  libigl's ``min_quad_with_fixed``, factored once for ``Q = Σ Kᵀ W K``.

This is the Gauss–Newton-like scheme the paper refers to; each step cannot
increase the energy of the fixed-target problem.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import igl
import numpy as np
import scipy.sparse as sp

from .errors import SolveError
from .terms import LocalState, Term

__all__ = ["LocalGlobalSolver", "IterationResult"]

# iterations over which the relative energy change is measured for convergence
_WINDOW = 5


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
        Seconds spent in ``local`` and ``solve`` steps.
    """

    X: np.ndarray
    energy: list = field(default_factory=list)
    iterations: int = 0
    converged: bool = False
    reason: str = ""
    timings: dict = field(default_factory=dict)


class LocalGlobalSolver:
    """Assemble and factor the quadratic form once; iterate many times.

    Parameters
    ----------
    terms : list of Term
    n : int
        Number of vertices.
    fixed : ndarray of int64, shape (b,)
        Vertices held at prescribed positions.
    """

    def __init__(self, terms: list[Term], n: int, fixed: np.ndarray):
        t0 = time.perf_counter()
        self.terms = terms
        self.n = n
        self.fixed = np.asarray(fixed, dtype=np.int64)
        free = np.ones(n, dtype=bool)
        free[self.fixed] = False
        self.free = np.flatnonzero(free)
        Q = sp.csr_matrix((n, n))
        for term in terms:
            Q = Q + term.K.T @ sp.diags(term.weights) @ term.K
        self.Q = sp.csc_matrix(Q)
        self.KtW = [sp.csr_matrix(term.K.T @ sp.diags(term.weights)) for term in terms]
        self.data = igl.min_quad_with_fixed_data()
        if self.free.size:
            ok = igl.min_quad_with_fixed_precompute(
                self.Q, self.fixed, sp.csc_matrix((0, n)), True, self.data
            )
            if ok is False:
                raise SolveError(
                    "the deformation system could not be factored (a part of the guest is not "
                    "held by any term); check that every guest component touches the seam"
                )
        self.factor_seconds = time.perf_counter() - t0

    def global_step(self, targets: list[np.ndarray], bc: np.ndarray) -> np.ndarray:
        """Minimiser of the fixed-target energy with ``X[fixed] = bc`` (shape (b, 3))."""
        B = np.zeros((self.n, 3))
        for KtW, t in zip(self.KtW, targets):
            B -= KtW @ t
        if not self.free.size:
            X = np.zeros((self.n, 3))
            X[self.fixed] = bc
            return X
        X = igl.min_quad_with_fixed_solve(self.data, B, bc, np.zeros((0, 3)))
        return np.asarray(X)

    def extend(self, displacement: np.ndarray) -> np.ndarray:
        """Smooth extension of a displacement of the fixed vertices to all vertices.

        Solves ``Q u = 0`` on the free vertices with ``u[fixed] = displacement``
        (shape (b, 3)); reuses the factorization. Returns shape (n, 3).
        """
        if not self.free.size:
            U = np.zeros((self.n, 3))
            U[self.fixed] = displacement
            return U
        return np.asarray(
            igl.min_quad_with_fixed_solve(
                self.data, np.zeros((self.n, 3)), displacement, np.zeros((0, 3))
            )
        )

    def bump(self) -> np.ndarray:
        """Response to a unit load with the fixed vertices at zero: ``Q φ = 1``, shape (n,)."""
        if not self.free.size:
            return np.zeros(self.n)
        out = igl.min_quad_with_fixed_solve(
            self.data, -np.ones((self.n, 1)), np.zeros((len(self.fixed), 1)), np.zeros((0, 1))
        )
        return np.asarray(out)[:, 0]

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
    ) -> IterationResult:
        """Iterate from ``X0`` (shape (n, 3)) until the iterates settle.

        One iteration is a local step (targets) followed by a global step
        (back-substitution): the map ``G``. With ``acceleration > 0`` the
        fixed-point iteration ``X ← G(X)`` is Anderson-accelerated over the
        last ``acceleration`` iterates; an accelerated iterate that raises the
        energy is rejected in favour of the plain step (and the history is
        restarted), so the energy decreases as in the plain iteration.

        Parameters
        ----------
        X0 : ndarray, shape (n, 3)
            Initial guess; its fixed rows are replaced by ``bc``.
        bc : ndarray, shape (b, 3)
            Positions of the fixed vertices.
        max_iterations : int
        tolerance : float
            Converged when the energy changed by less than ``tolerance`` times
            its value over the last few iterations and no vertex moves more
            than ``100 × tolerance × scale`` under one more iteration.
        time_limit : float, optional
            Wall-clock seconds after which the current iterate is returned
            (``converged=False``, ``reason="time_limit"``).
        scale : float
            Length scale of the step criterion (e.g. the mean edge length).
        acceleration : int
            Anderson history length; 0 for the plain local/global iteration.

        Returns
        -------
        IterationResult
        """
        start = time.perf_counter()
        clock = {"local": 0.0, "solve": 0.0}
        free = self.free

        def local(Y):
            t0 = time.perf_counter()
            state = LocalState(Y)
            targets = [term.target(state) for term in self.terms]
            e = self._energy(state, targets)
            clock["local"] += time.perf_counter() - t0
            if not np.isfinite(e):
                raise SolveError(
                    "the solve produced non-finite positions; the guest has degenerate or "
                    "collapsed faces — repair it with igljoin.clean and retry"
                )
            return targets, e

        def global_(targets):
            t0 = time.perf_counter()
            Z = self.global_step(targets, bc)
            clock["solve"] += time.perf_counter() - t0
            return Z

        X = np.array(X0, dtype=np.float64)
        X[self.fixed] = bc
        targets, e = local(X)
        energy = [e]
        g = global_(targets)
        r = (g - X)[free].ravel()
        dR: list[np.ndarray] = []
        dG: list[np.ndarray] = []
        result = IterationResult(X=g)
        for it in range(1, max_iterations + 1):
            cand = g
            if dR:
                gamma = np.linalg.lstsq(np.stack(dR, axis=1), r, rcond=None)[0]
                cand = g.copy()
                cand[free] = (g[free].ravel() - np.stack(dG, axis=1) @ gamma).reshape(-1, 3)
            targets, e_new = local(cand)
            if cand is not g and e_new > energy[-1]:
                # the accelerated iterate raised the energy: take the plain step instead
                dR.clear()
                dG.clear()
                cand = g
                targets, e_new = local(cand)
            g_new = global_(targets)
            r_new = (g_new - cand)[free].ravel()
            if acceleration > 0:
                dR.append(r_new - r)
                dG.append((g_new - g)[free].ravel())
                if len(dR) > acceleration:
                    dR.pop(0)
                    dG.pop(0)
            energy.append(e_new)
            g, r = g_new, r_new
            result.iterations = it
            step = float(np.abs(r).max()) if r.size else 0.0
            window = energy[max(0, len(energy) - 1 - _WINDOW)] - e_new
            if (
                it >= 2
                and abs(window) <= tolerance * max(e_new, 1e-300)
                and step <= 100.0 * tolerance * scale
            ):
                result.converged, result.reason = True, "tolerance"
                break
            if time_limit is not None and time.perf_counter() - start > time_limit:
                result.reason = "time_limit"
                break
        else:
            result.reason = "max_iterations"
        result.X = g
        result.energy = energy
        result.timings = dict(clock)
        return result

    def _energy(self, state: LocalState, targets: list[np.ndarray]) -> float:
        return float(sum(term.energy(state, t) for term, t in zip(self.terms, targets)))
