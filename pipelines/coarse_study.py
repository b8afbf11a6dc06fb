"""Why the two-level preconditioner failed on the tube, and what makes its count flatter.

Usage::

    python pipelines/coarse_study.py run tube 10000 [40000 ...]   # iterations table
    python pipelines/coarse_study.py pcg tube 2500 10000            # linear PCG counts
    python pipelines/coarse_study.py line tube 10000                # energy along steps
    python pipelines/coarse_study.py time tube 10000 [40000 ...]    # seconds, P against rebuilt
    python pipelines/coarse_study.py time tube 10000 cluster_size=40 rebuild_angle=0.3
    python pipelines/coarse_study.py paper 5                        # the six paper samples

``run`` joins the end-to-end tube (``tube``) or the partial patch
(``patch``) with about the given number of guest vertices four ways from
the same start, tolerance and quasi-Newton memory: L-BFGS on ``P`` (the
default), the two-level model as the join option uses it (rigid cluster
motions, built once at the start), with bending motions built once, and with
bending motions rebuilt when the guest has turned. It prints iterations,
rejected line-search trials, coarse builds, seconds (the model's set-up
included) and the final energy against the default run's (relative; negative
is lower), and the iteration at which each run first came within 1e-2 ..
1e-6 of the default's final energy.

``time`` runs ``P`` and the bending model rebuilt as the guest turns
(:data:`TIMED`) from the same start, and prints iterations, seconds of the
whole iteration, of the coarse set-up (clusters and first build) and of the
rebuilds apart, and the energy gap to ``P``'s run. With ``IGLJOIN_TREE``
set to another checkout, that checkout's package is timed (the same script
on two versions of the code, alternated by the caller).

``paper`` joins the six paper samples whole (``igljoin.JoinSolver`` and
``solve``, as the benchmark's median join) three ways, alternated over the
given number of rounds: the default (``P`` alone below
``igljoin.twolevel.AUTO_FROM_VERTICES``), the ``"auto"`` model forced on
(the threshold set to 0) and bending motions built once (no rebuild). It
prints per sample the iterations, the median join in ms, the model's own
seconds (clusters, values, projection, factorization) and builds, and the
energy gap to a long plain run, then the median join over the samples.

``pcg`` counts the conjugate-gradient iterations that solve the
Gauss–Newton model at the default run's minimum (random right-hand side,
residual 1e-6 in the preconditioner's norm) with ``P⁻¹`` and the additive
two-level forms: a linear measure of how well each coarse space captures
the slow modes, free of the line search.

``line`` evaluates the true energy along the fine (``−P⁻¹ g``), coarse
(``−C g``) and summed steps at a few iterates of the default run, against
the Gauss–Newton model's prediction: where the model's curvature is wrong
the ratio departs from 1.
"""

from __future__ import annotations

import inspect
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, os.environ.get("IGLJOIN_TREE", str(ROOT)))

import igljoin  # noqa: E402
from igljoin import newton, phantoms, twolevel  # noqa: E402

#: Scenario and guest vertices at guest_resolution 1.
_BASE = {"tube": ("end_to_end", 2436), "patch": ("partial_patch", 1180)}

#: The two-level models compared with the default run.
VARIANTS = {
    "rigid, built once": dict(bending=False, rebuild_angle=None),
    "bending, built once": dict(bending=True, rebuild_angle=None),
    "bending, rebuilt": dict(bending=True, rebuild_angle=0.2),
}


def join_solver(kind: str, vertices: float, length: str = "equal"):
    """A JoinSolver of the tube or patch with about ``vertices`` guest vertices."""
    scenario, base = _BASE[kind]
    r = float(np.sqrt(vertices / base))
    s = phantoms.paper_sample(scenario, length, guest_resolution=r)
    return igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)


def run(solver, model=None, **kw):
    """The join's iteration from its own start; returns ``(IterationResult, seconds)``."""
    ls, opt = solver.solver, solver.options
    settings = dict(
        max_iterations=kw.pop("max_iterations", 3000),
        tolerance=kw.pop("tolerance", opt.energy_tolerance),
        scale=solver.guest_mean_edge,
        acceleration=opt.acceleration,
    )
    t0 = time.perf_counter()
    out = ls.run(solver.initial_guess(), solver.corr.targets, model=model, **settings, **kw)
    return out, time.perf_counter() - t0


def _row(kind, n, name, res, seconds, e_ref, builds="") -> None:
    rel = (np.asarray(res.energy) - e_ref) / e_ref
    reach = [
        int(np.argmax(rel <= q)) if (rel <= q).any() else "-" for q in 10.0 ** -np.arange(2, 7)
    ]
    gap = (res.energy[-1] - e_ref) / e_ref
    print(
        f"| {kind} | {n} | {name} | {res.iterations} | {res.stats['rejected']} | {builds} "
        f"| {seconds:.1f} | {gap:+.1e} | {' / '.join(map(str, reach))} |",
        flush=True,
    )


def _reference(kind: str, vertices: float):
    """The solver of a case, its size and the factored ``P``'s run: ``(solver, n, run, s)``."""
    solver = join_solver(kind, vertices)
    # the first run of a process compiles the quasi-Newton kernels: not timed
    run(solver, max_iterations=2)
    base, seconds = run(solver)
    return solver, solver.solver.n, base, seconds


def table(kind: str, sizes: list) -> None:
    print("| case | n | model | iterations | rejected | builds | s | gap | reach 1e-2..1e-6 |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---|")
    for v in sizes:
        solver, n, base, seconds = _reference(kind, v)
        e_ref = base.energy[-1]
        _row(kind, n, "P", base, seconds, e_ref)
        for name, kw in VARIANTS.items():
            model = twolevel.TwoLevelModel(solver.solver, **kw)
            res, seconds = run(solver, model)
            _row(kind, n, name, res, seconds, e_ref, model.factorizations)


#: The model ``time`` compares with ``P``: the one ``preconditioner="auto"`` uses.
TIMED = dict(getattr(twolevel, "AUTO_MODEL", dict(bending=True, rebuild_angle=0.2)))


def timed(kind: str, sizes: list) -> None:
    # an older checkout's TwoLevelModel (IGLJOIN_TREE) takes fewer arguments: those it
    # does not know are left out (its policy: rebuilds from the first iteration, no cap)
    known = inspect.signature(twolevel.TwoLevelModel).parameters
    kw = {k: v for k, v in TIMED.items() if k in known}
    print("| case | n | model | iterations | rejected | builds | s | set-up s | rebuilds s | gap |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for v in sizes:
        solver, n, base, seconds = _reference(kind, v)
        e_ref = base.energy[-1]
        print(
            f"| {kind} | {n} | P | {base.iterations} | {base.stats['rejected']} | | "
            f"{seconds:.2f} | | | |",
            flush=True,
        )
        # and the first build of a process loads the compiled coarse kernels: not timed
        run(solver, twolevel.TwoLevelModel(solver.solver, **kw), max_iterations=2)
        model = twolevel.TwoLevelModel(solver.solver, **kw)
        first = {}

        def refresh(state, it, inner=model.refresh, first=first):
            t0 = time.perf_counter()
            out = inner(state, it)
            if it == 1:
                first["s"] = time.perf_counter() - t0
            return out

        model.refresh = refresh
        res, seconds = run(solver, model)
        total = res.timings["model"]
        gap = (res.energy[-1] - e_ref) / e_ref
        print(
            f"| {kind} | {n} | rebuilt | {res.iterations} | {res.stats['rejected']} "
            f"| {model.factorizations} | {seconds:.2f} | {first['s']:.2f} "
            f"| {total - first['s']:.2f} | {gap:+.1e} |",
            flush=True,
        )


def _model_product(ls, state):
    """``v ↦ H_ff v`` (3 n_free,) for the Gauss–Newton model at ``state``, from its factors."""
    factors = newton.gauss_newton_factors(ls.terms, state, ls.n)
    free = newton.dofs(ls.free)
    return lambda v: newton.factors_product(factors, free, ls.n, v)


def _unknowns(model) -> int:
    """The coarse unknowns of a built two-level model (``w`` per cluster)."""
    return model.motions.shape[2] * model._clusters


def _pcg(H, M, b, tol=1e-6, maxit=3000) -> int:
    x, r = np.zeros_like(b), b.copy()
    z = M(r)
    p, rz = z.copy(), r @ z
    start = np.sqrt(rz)
    for k in range(1, maxit + 1):
        Hp = H(p)
        a = rz / (p @ Hp)
        x += a * p
        r -= a * Hp
        z = M(r)
        rz_new = r @ z
        if np.sqrt(abs(rz_new)) <= tol * start:
            return k
        p = z + (rz_new / rz) * p
        rz = rz_new
    return maxit


def pcg(kind: str, sizes: list) -> None:
    for v in sizes:
        solver = join_solver(kind, v)
        ls = solver.solver
        state, _, _ = ls.local(run(solver)[0].X)
        nf = len(ls.free)

        def fine(r, ls=ls, nf=nf):
            return ls.factor.solve_free(r.reshape(nf, 3)).reshape(-1)

        b = np.random.default_rng(0).standard_normal(3 * nf)
        out = []
        H = _model_product(ls, state)
        for name, kw in {
            "rigid": dict(bending=False),
            "rigid and bending": dict(bending=True),
        }.items():
            model = twolevel.TwoLevelModel(ls, **kw)
            model.refresh(state, 1)
            count = _pcg(H, lambda r, m=model: fine(r) + m._coarse(r), b)
            out.append(f"{name} {count} ({_unknowns(model)} coarse unknowns)")
        print(f"{kind} n={ls.n}: P {_pcg(H, fine, b)}, " + ", ".join(out), flush=True)


def line(kind: str, vertices: float, at=(0, 20, 60)) -> None:
    solver = join_solver(kind, vertices)
    ls = solver.solver
    for k in at:
        X = run(solver, max_iterations=k)[0].X if k else solver.initial_guess()
        X[ls.fixed] = solver.corr.targets
        state, e, G = ls.local(X)
        g = G[ls.free]
        model = twolevel.TwoLevelModel(ls)
        model.refresh(state, 1)
        H = _model_product(ls, state)
        steps = {"fine": -ls.factor.solve_free(g)}
        steps["coarse"] = -model._coarse(g.reshape(-1)).reshape(g.shape)
        steps["sum"] = steps["fine"] + steps["coarse"]
        for name, d in steps.items():
            gd = float(np.vdot(g, d))
            dHd = float(d.reshape(-1) @ H(d.reshape(-1)))
            ts = np.array([0.05, 0.25, 1.0])
            es = []
            for t in ts:
                Xt = X.copy()
                Xt[ls.free] += t * d
                es.append(ls.local(Xt, state.rotations)[1])
            # true curvature over the model's, from E(t) = E + 2 t gᵀd + t² c
            ratio = (np.asarray(es) - e - 2 * ts * gd) / ts**2 / dHd
            print(
                f"{kind} n={ls.n} it {k}: {name:6s} model's best t {-gd / dHd:.2f}, "
                f"true/model curvature at t=0.05, 0.25, 1: {np.round(ratio, 2)}",
                flush=True,
            )


def paper(rounds: int) -> None:
    # the preconditioner choices compared: the threshold and model "auto" reads (TIMED as
    # the command line left it); both are put back at the end
    paper_choices = {
        "P": (twolevel.AUTO_FROM_VERTICES, dict(TIMED)),
        "auto forced": (0, dict(TIMED)),
        "bending once": (0, dict(bending=True)),
    }
    before = twolevel.AUTO_FROM_VERTICES, twolevel.AUTO_MODEL
    try:
        _paper(rounds, paper_choices)
    finally:
        twolevel.AUTO_FROM_VERTICES, twolevel.AUTO_MODEL = before


def _paper(rounds: int, choices: dict) -> None:
    import statistics

    cases = [
        (sc, ln) for sc in ("end_to_end", "partial_patch") for ln in ("shorter", "equal", "longer")
    ]
    samples = [phantoms.paper_sample(sc, ln) for sc, ln in cases]

    def join(s, name):
        twolevel.AUTO_FROM_VERTICES, twolevel.AUTO_MODEL = choices[name]
        t0 = time.perf_counter()
        solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
        r = solver.solve()
        return time.perf_counter() - t0, r, solver

    names = list(choices)
    for s in samples:  # compiled kernels loaded, caches warm: not timed
        for name in names:
            join(s, name)
    print(
        "| sample | " + " | ".join(f"{n}: it / ms / model ms (builds) / gap" for n in names) + " |"
    )
    print("|---|" + "---|" * len(names))
    medians = {n: [] for n in names}
    for (sc, ln), s in zip(cases, samples):
        solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
        e_ref = solver.solve(acceleration=0, energy_tolerance=1e-12, max_iterations=30000)
        e_ref = e_ref.energy[-1]
        seconds, last = {n: [] for n in names}, {}
        for k in range(rounds):
            for name in names if k % 2 == 0 else names[::-1]:
                t, r, solver = join(s, name)
                seconds[name].append(t)
                last[name] = (r, solver.last_model)
        cells = []
        for name in names:
            r, model = last[name]
            ms = 1000 * statistics.median(seconds[name])
            medians[name].append(ms)
            own = 0.0 if model is None else 1000 * sum(model.seconds.values())
            builds = 0 if model is None else model.factorizations
            gap = (r.energy[-1] - e_ref) / e_ref
            cells.append(f"{r.iterations} / {ms:.1f} / {own:.1f} ({builds}) / {gap:+.1e}")
        print(f"| {sc}/{ln} | " + " | ".join(cells) + " |", flush=True)
    print(
        "median join ms: "
        + ", ".join(f"{n} {statistics.median(v):.1f}" for n, v in medians.items())
    )


def main(argv: list) -> None:
    # key=value arguments replace TwoLevelModel arguments of TIMED (numbers or None)
    for arg in [a for a in argv if "=" in a]:
        key, value = arg.split("=")
        TIMED[key] = None if value == "None" else float(value)
        if key in ("cluster_size", "first_rebuild", "max_rebuilds") and value != "None":
            TIMED[key] = int(TIMED[key])
    argv = [a for a in argv if "=" not in a]
    if (
        not argv
        or argv[0] not in ("run", "pcg", "line", "time", "paper")
        or (argv[0] != "paper" and len(argv) < 3)
    ):
        sys.exit(__doc__)
    if argv[0] == "paper":
        paper(int(argv[1]) if len(argv) > 1 else 5)
        return
    what, kind, sizes = argv[0], argv[1], [float(v) for v in argv[2:]]
    {"run": table, "pcg": pcg, "time": timed}.get(what, lambda k, s: line(k, s[0]))(kind, sizes)


if __name__ == "__main__":
    main(sys.argv[1:])
