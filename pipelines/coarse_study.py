"""Why the two-level preconditioner fails on the tube, and what makes the count flat on both.

Usage::

    python pipelines/coarse_study.py diagnose tube 10000
    python pipelines/coarse_study.py run tube 10000 default additive ...

Study script: prints a table of iterations, rejected line-search trials,
seconds and the energy gap to the default run (relative).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import igljoin  # noqa: E402
from igljoin import newton, phantoms, twolevel  # noqa: E402

_BASE = {"tube": ("end_to_end", 2436), "patch": ("partial_patch", 1180)}


def sample(kind: str, vertices: float, length: str = "equal"):
    scenario, base = _BASE[kind]
    r = float(np.sqrt(vertices / base))
    return phantoms.paper_sample(scenario, length, guest_resolution=r)


def join_solver(kind, vertices, length="equal"):
    s = sample(kind, vertices, length)
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)


def run(solver, model=None, **kw):
    ls, opt = solver.solver, solver.options
    X0 = solver.initial_guess()
    settings = dict(
        max_iterations=kw.pop("max_iterations", 3000),
        tolerance=kw.pop("tolerance", opt.energy_tolerance),
        scale=solver.guest_mean_edge,
        acceleration=kw.pop("acceleration", opt.acceleration),
    )
    t0 = time.perf_counter()
    out = ls.run(X0, solver.corr.targets, model=model, **settings, **kw)
    return out, time.perf_counter() - t0


def diagnose(kind, vertices, at=(0, 20, 60)):
    """Energy along the fine and coarse parts of the first step direction at a few iterates."""
    solver = join_solver(kind, vertices)
    ls = solver.solver
    print(f"{kind} {vertices}: n={ls.n}")
    for k in at:
        if k:
            res, _ = run(solver, max_iterations=k)
            X = res.X
        else:
            X0 = solver.initial_guess()
            X = X0.copy()
            X[ls.fixed] = solver.corr.targets
        state, e, G = ls.local(X)
        g = G[ls.free]
        for label, built_at in (("start", None), ("here", state)):
            model = twolevel.TwoLevelModel(ls)
            if built_at is None:
                X0 = solver.initial_guess()
                X0[ls.fixed] = solver.corr.targets
                s0, _, _ = ls.local(X0)
                model.refresh(s0, 1)
            else:
                model.refresh(state, 1)
            flat = g.reshape(-1)
            dc = -model._coarse(flat).reshape(g.shape)
            df = -ls.factor.solve_free(g)
            H = newton.gauss_newton_factors(ls.terms, state, ls.n)
            model_here = twolevel.TwoLevelModel(ls)
            model_here.factors = H
            for name, d in (("fine", df), ("coarse", dc), ("sum", df + dc)):
                gd = float(np.vdot(g, d))
                dHd = float(np.vdot(d.reshape(-1), model_here._model(d.reshape(-1))))
                # true energy along d
                ts = np.array([0.05, 0.1, 0.25, 0.5, 1.0])
                es = []
                for t in ts:
                    Xt = X.copy()
                    Xt[ls.free] = X[ls.free] + t * d
                    es.append(ls.local(Xt, state.rotations)[1])
                es = np.array(es)
                # model: E + 2 t gd + t^2 dHd  (H is half the GN Hessian; E = sum squares)
                t_model = -gd / dHd if dHd > 0 else np.inf
                # curvature from the smallest step: (E(t) - E - 2 t gd) / t^2
                curv = (es - e - 2 * ts * gd) / ts**2
                best = ts[np.argmin(es)]
                print(
                    f"  it {k:4d} coarse@{label:5s} {name:6s} gd={gd:10.3e} t*_model={t_model:8.3f} "
                    f"best_t={best:5.2f} dE(1)={es[-1] - e:10.3e} "
                    f"curv true/model at t=.05,.25,1: "
                    + " ".join(f"{c / dHd:6.2f}" for c in curv[[0, 2, 4]])
                )


def main(argv):
    if argv[0] == "diagnose":
        diagnose(argv[1], float(argv[2]))


if __name__ == "__main__":
    main(sys.argv[1:])
