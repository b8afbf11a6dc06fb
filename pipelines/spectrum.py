"""Why the join needs the iterations it needs: the spectrum of the preconditioned Hessian.

The accelerated iteration is L-BFGS whose initial inverse Hessian is the
factored preconditioner ``P`` (see ``igljoin/solve.py``). Its rate is set by
how well ``P`` models the true Hessian ``H`` of the energy at the minimum:
the generalized eigenvalues ``H v = λ P v``. This script measures them on
the end-to-end paper sample (``H`` by central differences of the exact
gradient, dense), and then runs the join again
with an *oracle* preconditioner that corrects ``P`` on the ``k`` softest
eigenvectors (``P⁻¹ + V_k (Λ_k⁻¹ − 1) V_kᵀ``, exact at the minimum), to
show how many iterations a perfect coarse-space correction of those modes
could save.

Usage::

    python pipelines/spectrum.py [--resolution 1.0] [--out docs/spectrum.json]

At the paper's size (resolution 1, 2,512 guest vertices) it takes about two
minutes and 3 GB (dense matrices of the 7,047 free coordinates; the
eigenproblem grows with the cube of the guest size); ``--resolution 0.45``
takes seconds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.linalg as sla

import igljoin
from igljoin import phantoms
from igljoin.atomic import atomic_write_text


def free_hessian(solver: igljoin.JoinSolver, X: np.ndarray) -> np.ndarray:
    """Half the Hessian of the energy on the free coordinates at ``X`` (n, 3), shape (3f, 3f).

    Central differences of the exact half-gradient, symmetrised (the scale
    ``P`` models: the solver's step is ``−P⁻¹ g`` with ``g`` half the
    gradient); coordinates
    are ordered vertex-major (``3 i + c``).
    """
    ls = solver.solver
    free = ls.free
    h = 1e-6 * solver.guest_mean_edge

    def gradient(Y):
        return ls.local(Y)[2][free].reshape(-1)

    N = 3 * free.size
    H = np.empty((N, N))
    for k in range(N):
        i, c = divmod(k, 3)
        plus, minus = X.copy(), X.copy()
        plus[free[i], c] += h
        minus[free[i], c] -= h
        # Jacobian of the half-gradient, the matrix P models (the solver steps by -P⁻¹ g)
        H[:, k] = (gradient(plus) - gradient(minus)) / (2.0 * h)
    return 0.5 * (H + H.T)


def oracle_iterations(sample, values, vectors, k: int) -> int:
    """Iterations of the join with ``P⁻¹`` corrected on the ``k`` softest eigenvectors."""
    solver = igljoin.JoinSolver(sample.host, sample.guest, sample.host_curve, sample.guest_curve)
    factor = solver.solver.factor
    plain_solve = factor.solve_free
    Vk, correction = vectors[:, :k], 1.0 / values[:k] - 1.0

    def corrected(b):
        x = plain_solve(b)
        if k and b.shape[1] == 3:
            x = x + (Vk @ (correction * (Vk.T @ b.reshape(-1)))).reshape(b.shape)
        return x

    factor.solve_free = corrected
    return int(solver.solve().iterations)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=float, default=1.0)
    parser.add_argument("--out", type=Path, default=Path("docs/spectrum.json"))
    args = parser.parse_args(argv)
    start = time.perf_counter()
    sample = phantoms.paper_sample("end_to_end", "equal", resolution=args.resolution)
    solver = igljoin.JoinSolver(sample.host, sample.guest, sample.host_curve, sample.guest_curve)
    default_iterations = int(solver.solve().iterations)
    minimum = solver.solve(energy_tolerance=1e-12, max_iterations=5000)
    H = free_hessian(solver, minimum.guest.V)
    ls = solver.solver
    free = ls.free
    P = np.kron(ls.P[free][:, free].toarray(), np.eye(3))
    Q = np.kron(ls.Q[free][:, free].toarray(), np.eye(3))
    values, vectors = sla.eigh(H, P)
    q_values = sla.eigh(H, Q, eigvals_only=True)
    out = {
        "sample": "end_to_end/equal",
        "resolution": args.resolution,
        "guest_vertices": int(ls.n),
        "free_coordinates": int(3 * free.size),
        "iterations_default": default_iterations,
        "P": {
            "min": float(values.min()),
            "max": float(values.max()),
            "condition": float(values.max() / values.min()),
            "below": {str(t): int((values < t).sum()) for t in (0.05, 0.1, 0.2, 0.3)},
        },
        "Q": {
            "min": float(q_values.min()),
            "max": float(q_values.max()),
            "condition": float(q_values.max() / q_values.min()),
        },
        "oracle_iterations": {
            str(k): oracle_iterations(sample, values, vectors, k) for k in (0, 10, 30, 100)
        },
    }
    out["seconds"] = time.perf_counter() - start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
