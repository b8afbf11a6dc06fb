"""Benchmark the join: time per phase, iterations, memory, libigl ARAP, convergence, scaling.

Usage::

    python pipelines/benchmark.py              # full run, writes docs/benchmarks.{json,md}
    python pipelines/benchmark.py --quick      # a few minutes; writes benchmark-quick/
    python pipelines/benchmark.py --million    # also the 1M-vertex guest (minutes, ~GBs)

Every case runs in its own subprocess (so peak memory, ``ru_maxrss``, is per
case). For each case the script reports the median wall time of a full
``JoinSolver(...).solve()`` (= ``igljoin.join``) and of its phases, the
iterations to convergence, and, on the same refined guest with the same
fixed seam (positions = our seam targets), the same initial guess and the
same number of iterations, the time of libigl's own C++ ARAP
(``igl.arap_precomputation`` + ``igl.arap_solve``). On the paper-sized
samples it also checks that the accelerated result reaches the energy of a
long plain local/global run (``acceleration=0``, tight tolerance), and it
measures the throughput of 1 against 2 local worker processes.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import json
import multiprocessing as mp
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import igljoin  # noqa: E402
from igljoin import phantoms  # noqa: E402
from igljoin.atomic import atomic_write_text  # noqa: E402

SAMPLES = [
    (sc, ln) for sc in ("end_to_end", "partial_patch") for ln in ("shorter", "equal", "longer")
]

#: The paper's own figures (§5, Intel Pentium 4, 3 GHz, 1 GB RAM).
PAPER = {
    "end_to_end": {"seconds": 70.0, "points": 2494, "hard": 522, "soft": 29688},
    "partial_patch": {"seconds": 13.0, "points": 1509, "hard": 1218, "soft": 17967},
}

#: Guest vertices of the paper's partial patch per guest_resolution² (measured: the
#: count grows a little slower than the square, 1,305 at 1 and ~1,180 r² at r = 3-30).
_PATCH_GUEST = 1180

#: Guest vertices of the end-to-end artery per guest_resolution² (87 x 28 rings at 1).
_TUBE_GUEST = 2436

#: Relative energy gap to the long plain run that counts as "the same minimum".
CONVERGENCE_GAP = 1e-6

_BLAS_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


# -- one case (runs inside a worker subprocess) ------------------------------------------------


#: The large host: a 350-degree aortic wall 300 mm long (a thoracic aorta's length) with
#: the paper's patch hole, meshed to about 460k vertices (target edge 0.33 mm).
_BIG_HOST = {"radius": 15.0, "height": 300.0, "arc_deg": 350.0, "target_edge": 0.33}


def _sample(spec: dict):
    if spec["kind"] == "host":
        # the paper's partial patch guest on a large host with the same hole (its vertices
        # 0..n_hole-1, as on the paper's host)
        s = phantoms.paper_sample("partial_patch", "equal")
        h = _BIG_HOST
        host = phantoms.aortic_wall(
            h["radius"],
            h["height"],
            h["arc_deg"],
            hole_axes=(8.0, 5.0),
            n_hole=len(s.host_curve),
            target_edge=h["target_edge"],
            name="large host",
        )
        curve = np.arange(len(s.host_curve), dtype=np.int64)
        assert np.array_equal(host.V[curve], s.host.V[s.host_curve])
        return dataclasses.replace(s, name="large host", host=host, host_curve=curve)
    if spec["kind"] == "paper":
        return phantoms.paper_sample(spec["scenario"], spec["length"])
    if spec["kind"] == "tube":
        # the end-to-end artery, a structured tube: no Triangle run (libigl's Triangle
        # crashes on the ~1M-vertex patch outline)
        r = float(np.sqrt(spec["vertices"] / _TUBE_GUEST))
        return phantoms.paper_sample("end_to_end", "equal", guest_resolution=r)
    r = float(np.sqrt(spec["vertices"] / _PATCH_GUEST))
    return phantoms.paper_sample("partial_patch", "equal", guest_resolution=r)


def _timed_join(s, **options):
    """Wall time of ``JoinSolver(...).solve()`` (what ``igljoin.join`` does)."""
    t0 = time.perf_counter()
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)
    res = solver.solve()
    return time.perf_counter() - t0, solver, res


def _arap_seconds(solver, iterations: int) -> float:
    """libigl's ARAP on our refined guest, seam fixed at our targets, same start and iterations."""
    import igl

    c = solver.corr
    X0 = solver.initial_guess()
    t0 = time.perf_counter()
    data = igl.ARAPData()
    data.max_iter = max(int(iterations), 1)
    igl.arap_precomputation(c.V, c.F, 3, c.seam.astype(np.int32), data)
    igl.arap_solve(c.targets, data, X0)
    return time.perf_counter() - t0


def _slider_targets(targets: np.ndarray, step: int) -> np.ndarray:
    """Seam targets turned by ``step`` degrees about an axis through their centroid (a slider)."""
    from scipy.spatial.transform import Rotation

    c = targets.mean(axis=0)
    R = Rotation.from_rotvec(np.radians(float(step)) * np.array([1.0, 0.0, 0.0])).as_matrix()
    return (targets - c) @ R.T + c


def _resolves(solver, first, steps: int) -> dict:
    """Re-solves through one ``JoinSolver`` with new seam targets (1° slider steps).

    *cold*: ``solve(targets)`` from the initial guess; *warm*: ``solve(targets,
    start=previous)``. Both reuse the factorization (counted).
    """
    from igljoin.linsolve import FixedQuadratic

    made = FixedQuadratic.made
    cold, warm, it_cold, it_warm, gaps = [], [], [], [], []
    prev = first
    for k in range(1, steps + 1):
        T = _slider_targets(first.seam_targets, k)
        t0 = time.perf_counter()
        a = solver.solve(T)
        cold.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        b = solver.solve(T, start=prev)
        warm.append(time.perf_counter() - t0)
        prev = b
        it_cold.append(int(a.iterations))
        it_warm.append(int(b.iterations))
        gaps.append((b.energy[-1] - a.energy[-1]) / abs(a.energy[-1]))
    return {
        "cold_seconds": statistics.median(cold),
        "warm_seconds": statistics.median(warm),
        "cold_iterations": it_cold,
        "warm_iterations": it_warm,
        "max_warm_cold_gap": float(max(gaps)),
        "factorizations": FixedQuadratic.made - made,
    }


def _earlier_runs(runs) -> list[dict]:
    """Earlier runs' machine records as a flat list (older files nested them one in another)."""
    if isinstance(runs, dict):
        inner = dict(runs)
        return [inner, *_earlier_runs(inner.pop("earlier_runs", []))]
    return list(runs)


def _with_model(solver, res, model) -> dict:
    """The same join with ``model`` as the quasi-Newton initial inverse Hessian.

    Same start, seam targets, tolerance and quasi-Newton memory as the join's
    own iteration; only the initial inverse Hessian ``P⁻¹`` is replaced.
    Returns its iterations, time (including the model's set-up) and the
    energy gap to the join's result (negative: it ended lower).
    """
    ls, opt = solver.solver, solver.options
    X0 = solver.initial_guess()
    t0 = time.perf_counter()
    run = ls.run(
        X0,
        solver.corr.targets,
        max_iterations=opt.max_iterations,
        tolerance=opt.energy_tolerance,
        scale=solver.guest_mean_edge,
        acceleration=opt.acceleration,
        time_limit=opt.time_limit,
        model=model,
    )
    seconds = time.perf_counter() - t0
    e = float(res.energy[-1])
    return {
        "iterations": int(run.iterations),
        "converged": bool(run.converged),
        "seconds": seconds,
        "model_seconds": float(run.timings.get("model", 0.0)),
        "energy": float(run.energy[-1]),
        "relative_gap": (float(run.energy[-1]) - e) / abs(e),
    }


def _newton(solver, res) -> dict:
    """The join with the Gauss–Newton model, assembled and factored once (igljoin.newton)."""
    from igljoin.newton import NewtonModel

    model = NewtonModel(solver.solver)
    out = _with_model(solver, res, model)
    out["assemble_seconds"] = model.seconds["assemble"]
    out["factor_seconds"] = model.seconds["factor"]
    return out


#: The ``preconditioner`` options run beside the join (each a re-solve of its solver, the
#: factorization reused): the factored ``P`` alone, the rigid coarse space built once, and
#: the join's choice by size (``"auto"``: ``P`` below ``igljoin.twolevel.AUTO_FROM_VERTICES``
#: free vertices, the bending coarse space rebuilt as the guest turns from there).
_PRECONDITIONERS = ("factored", "two-level", "auto")


def _preconditioners(solver) -> dict:
    """The join with each ``preconditioner`` option, from the same start and settings.

    Every run is ``solver.solve(preconditioner=...)``; *seconds* is its
    iteration including the model's set-up and rebuilds; *relative_gap* its
    final energy against the factored ``P``'s run (negative: lower).
    """
    own = solver.options.preconditioner
    runs = {}
    try:
        for choice in _PRECONDITIONERS:
            r = solver.solve(preconditioner=choice)
            run = solver.last_run
            runs[choice] = {
                "iterations": int(r.iterations),
                "converged": bool(r.converged),
                "seconds": float(r.timings["iterate"]),
                "model_seconds": float(run.timings["model"]),
                "builds": int(run.stats["model_builds"]),
                "energy": float(r.energy[-1]),
            }
    finally:
        solver.update(preconditioner=own)
    e = runs["factored"]["energy"]
    for r in runs.values():
        r["relative_gap"] = (r["energy"] - e) / abs(e)
    return runs


def run_case(spec: dict) -> dict:
    """Time one case; returns plain JSON."""
    t0 = time.perf_counter()
    s = _sample(spec)
    build = time.perf_counter() - t0
    runs = int(spec["runs"])
    first = None
    if spec.get("warmup", True):
        first = _timed_join(s)[0]
    walls, phases, arap = [], [], []
    solver = res = None
    options = {"time_limit": spec["time_limit"]} if spec.get("time_limit") else {}
    options.update(spec.get("options", {}))
    for _ in range(runs):
        wall, solver, res = _timed_join(s, **options)
        walls.append(wall)
        phases.append(res.timings)
    weld = None
    weld_in_metrics = getattr(res, "_merged", None) is not None
    if hasattr(res, "merged") and not weld_in_metrics:
        t1 = time.perf_counter()
        try:
            res.merged  # noqa: B018 - the weld is computed on first access
            weld = time.perf_counter() - t1
        except igljoin.WeldError:
            weld = None
    for _ in range(int(spec.get("arap_runs", runs))):
        arap.append(_arap_seconds(solver, res.iterations))
    med = {k: statistics.median(p[k] for p in phases) for k in phases[0]}
    run = solver.last_run
    out = {
        "spec": spec,
        "build_seconds": build,
        "guest_vertices": int(s.guest.n_vertices),
        "host_vertices": int(s.host.n_vertices),
        "host_faces": int(s.host.n_faces),
        "counts": res.counts,
        "converged": bool(res.converged),
        "stop_reason": res.stop_reason,
        "iterations": int(res.iterations),
        "stats": run.stats,
        "energy": float(res.energy[-1]),
        "backend": solver.solver.backend,
        "join_seconds": statistics.median(walls),
        "join_seconds_all": walls,
        "phases": {
            "setup": med["select"] + med["correspond"] + med["terms"] + med["initial_guess"],
            "factor": med["factor"],
            "local": med["local"],
            "back_solve": med["back_solve"],
            "other_iterate": med["iterate"] - med["local"] - med["back_solve"],
            "metrics": med["metrics"],
            "weld": weld,
            "weld_in_metrics": weld_in_metrics,
        },
        "phases_raw": med,
        "arap_seconds": statistics.median(arap) if arap else None,
        "first_join_seconds": first,
    }
    if spec.get("resolves"):
        out["resolve"] = _resolves(solver, res, int(spec["resolves"]))
    if spec.get("newton"):
        out["newton"] = _newton(solver, res)
    if spec.get("twolevel"):
        out["twolevel"] = _preconditioners(solver)
    if spec["kind"] == "host":
        # the same join with the whole host checked and selected (the path of a small
        # host, and of every host before the neighbourhood checks), back to back
        module = sys.modules["igljoin.join"]
        kept = module.HOST_CHECK_ALL_FACES
        whole = []
        try:
            module.HOST_CHECK_ALL_FACES = 1 << 62
            for _ in range(3):
                whole.append(_timed_join(s)[0])
        finally:
            module.HOST_CHECK_ALL_FACES = kept
        out["whole_host_join_seconds"] = statistics.median(whole)
    if out["arap_seconds"]:
        core = med["factor"] + med["iterate"]
        out["ratio_core"] = core / out["arap_seconds"]
        out["ratio_full"] = out["join_seconds"] / out["arap_seconds"]
    plain = spec.get("plain_iterations")
    if plain:
        t1 = time.perf_counter()
        p = solver.solve(acceleration=0, energy_tolerance=1e-12, max_iterations=int(plain))
        e_plain = float(p.energy[-1])
        gap = (out["energy"] - e_plain) / abs(e_plain)
        out["plain"] = {
            "iterations": int(p.iterations),
            "converged": bool(p.converged),
            "energy": e_plain,
            "seconds": time.perf_counter() - t1,
            "relative_gap": gap,
            "ok": bool(gap <= CONVERGENCE_GAP),
        }
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def _in_subprocess(spec: dict, timeout: float) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"case {spec} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["subprocess_seconds"] = time.perf_counter() - t0
    return out


# -- throughput: 1 vs 2 local worker processes -------------------------------------------------


def _cap_blas_threads() -> None:
    """Worker initializer: one BLAS/OpenMP thread per worker.

    The variables are also set in the parent before the pool starts, so a
    spawned worker has them before it imports numpy; setting them here covers
    executors that import first.
    """
    for var in _BLAS_VARS:
        os.environ[var] = "1"


def _throughput_case(args) -> float:
    host, guest, host_curve, guest_curve = args
    t0 = time.perf_counter()
    igljoin.JoinSolver(host, guest, host_curve, guest_curve).solve()
    return time.perf_counter() - t0


def _start_worker() -> None:
    """Worker initializer: cap the threads, then warm up with a small join.

    The join imports igljoin and loads its compiled kernels, so no timed
    case pays for them; as an initializer it runs once in every worker
    before that worker takes any task.
    """
    _cap_blas_threads()
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve).solve()


def _worker_pid(_: int) -> int:
    """This worker's process id, after a short pause so that idle workers get tasks too."""
    time.sleep(0.05)
    return os.getpid()


def _wait_for_workers(ex: cf.ProcessPoolExecutor, workers: int, timeout: float = 120.0) -> int:
    """Block until ``workers`` distinct workers have answered (each is then started and warm)."""
    deadline = time.perf_counter() + timeout
    seen: set[int] = set()
    while len(seen) < workers and time.perf_counter() < deadline:
        seen.update(ex.map(_worker_pid, range(4 * workers)))
    return len(seen)


def _timed_batch(ex: cf.ProcessPoolExecutor, cases: list) -> tuple[float, list[float]]:
    """Wall time of the whole batch and each case's time inside its worker."""
    t0 = time.perf_counter()
    per_case = list(ex.map(_throughput_case, cases))
    return time.perf_counter() - t0, per_case


def throughput(n_cases: int, rounds: int = 3) -> dict:
    """Wall time of ``n_cases`` paper-sized joins with 1 and with 2 worker processes.

    Both pools stay up; each round times the batch on one pool and then on
    the other (alternating which goes first), so that the two walls of a
    round see the same machine load. The scaling is the median over the
    rounds of ``wall(1 worker) / wall(2 workers)``.
    """
    cases = []
    for i in range(n_cases):
        sc, ln = SAMPLES[i % len(SAMPLES)]
        s = phantoms.paper_sample(sc, ln, irregularity=0.2, seed=i)
        cases.append(((s.host.V, s.host.F), (s.guest.V, s.guest.F), s.host_curve, s.guest_curve))
    saved = {var: os.environ.get(var) for var in _BLAS_VARS}
    for var in _BLAS_VARS:
        os.environ[var] = "1"
    ctx = mp.get_context("spawn")
    walls: dict[int, list[float]] = {1: [], 2: []}
    per_case: dict[int, list[float]] = {1: [], 2: []}
    ready = {}
    try:
        with (
            cf.ProcessPoolExecutor(1, mp_context=ctx, initializer=_start_worker) as one,
            cf.ProcessPoolExecutor(2, mp_context=ctx, initializer=_start_worker) as two,
        ):
            pools = {1: one, 2: two}
            # every worker started and warm (imports, compiled kernels) before the clock
            ready = {w: _wait_for_workers(ex, w) for w, ex in pools.items()}
            for r in range(rounds):
                for w in (1, 2) if r % 2 == 0 else (2, 1):
                    wall, times = _timed_batch(pools[w], cases)
                    walls[w].append(wall)
                    per_case[w].extend(times)
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
    out: dict = {"cases": n_cases, "rounds": rounds}
    for w in (1, 2):
        wall = statistics.median(walls[w])
        out[str(w)] = {
            "wall_seconds": wall,
            "walls": walls[w],
            "cases_per_second": n_cases / wall,
            "median_case_seconds": statistics.median(per_case[w]),
            "warm_workers": ready.get(w, 0),
        }
    out["round_scalings"] = [a / b for a, b in zip(walls[1], walls[2])]
    out["scaling"] = statistics.median(out["round_scalings"])
    return out


# -- report ------------------------------------------------------------------------------------


def _machine() -> dict:
    import igl
    import scipy

    info = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "libigl": getattr(igl, "__version__", "2.6"),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "backends": igljoin.linsolve.available_backends(),
    }
    try:
        import cholespy

        info["cholespy"] = cholespy.__version__
    except ImportError:
        pass
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gb"] = round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    info["load_average_start"] = os.getloadavg()
    return info


def _ms(x) -> str:
    return "—" if x is None else f"{1e3 * x:,.1f}"


def _s(x) -> str:
    return "—" if x is None else f"{x:,.2f}"


def markdown(results: dict) -> str:
    """The tables of ``docs/benchmarks.md``."""
    lines = []
    cases = results["cases"]
    lines += [
        "### Full join and its phases",
        "",
        "Medians over the runs, milliseconds. *setup*: validation, curve selection and "
        "pairing, correspondence, terms, initial guess; *local*: local steps (rotations, "
        "targets, energy, gradient); *back-solve*: back-substitutions; *metrics*: the "
        "result's measurements (they include the weld and its self-intersection check when "
        "the join does them); *other*: the rest of the iteration (quasi-Newton updates, "
        "convergence test).",
        "",
        "| case | guest vertices | join (ms) | iterations | setup | factor | local | back-solve "
        "| other | metrics | peak RSS (MB) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in cases:
        p = c["phases"]
        its = str(c["iterations"])
        if not c["converged"]:
            its += f" ({c['stop_reason'].replace('_', ' ')})"
        metrics = _ms(p["metrics"])
        if p["weld"] is not None:
            metrics += f" + weld {_ms(p['weld'])}"
        lines.append(
            f"| {c['name']} | {c['counts']['points']:,} | {_ms(c['join_seconds'])} | "
            f"{its} | {_ms(p['setup'])} | {_ms(p['factor'])} | {_ms(p['local'])} | "
            f"{_ms(p['back_solve'])} | {_ms(p['other_iterate'])} | {metrics} | "
            f"{c['peak_rss_mb']:,.0f} |"
        )
    lines += [
        "",
        "### Against libigl's C++ ARAP",
        "",
        "`igl.arap_precomputation` + `igl.arap_solve` on the same refined guest, seam fixed at "
        "our targets, same initial guess, `max_iter` = our iterations. *core* = our "
        "factorization + iteration; *full* = our whole join. Ratios below 1 mean igljoin is "
        "faster.",
        "",
        "| case | iterations | ARAP (ms) | ours core (ms) | ours full (ms) | ratio core "
        "| ratio full |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for c in cases:
        core = c["phases_raw"]["factor"] + c["phases_raw"]["iterate"]
        lines.append(
            f"| {c['name']} | {c['iterations']} | {_ms(c.get('arap_seconds'))} | {_ms(core)} | "
            f"{_ms(c['join_seconds'])} | {_s(c.get('ratio_core'))} | {_s(c.get('ratio_full'))} |"
        )
    checked = [c for c in cases if "plain" in c]
    if checked:
        lines += [
            "",
            "### Convergence: accelerated against a long plain run",
            "",
            "Plain local/global (`acceleration=0`, `energy_tolerance=1e-12`) from the same start. "
            "Gap = (E_accelerated − E_plain) / E_plain; it must be ≤ 1e-6 (negative: the "
            "accelerated run ended lower).",
            "",
            "| case | accelerated iterations | plain iterations | plain converged | plain (s) "
            "| gap | ok |",
            "|---|---:|---:|---|---:|---:|---|",
        ]
        for c in checked:
            p = c["plain"]
            lines.append(
                f"| {c['name']} | {c['iterations']} | {p['iterations']} | "
                f"{'yes' if p['converged'] else 'no'} | {p['seconds']:.1f} | "
                f"{p['relative_gap']:.1e} | {'yes' if p['ok'] else '**no**'} |"
            )
    lines += [
        "",
        "### The paper's figures beside ours",
        "",
        "| scenario | paper: points / hard / soft | paper time | ours: points / hard / soft "
        "| ours (ms, median of the three lengths) |",
        "|---|---|---:|---|---:|",
    ]
    for sc, ref in PAPER.items():
        mine = [c for c in cases if c["spec"].get("scenario") == sc]
        if not mine:
            continue
        eq = next((c for c in mine if c["spec"]["length"] == "equal"), mine[0])
        k = eq["counts"]
        lines.append(
            f"| {sc} | {ref['points']:,} / {ref['hard']:,} / {ref['soft']:,} | "
            f"{ref['seconds']:.0f} s (Pentium 4) | {k['points']:,} / {k['hard']:,} / "
            f"{k['soft']:,} | {_ms(statistics.median(c['join_seconds'] for c in mine))} |"
        )
    tp = results.get("throughput")
    if tp:
        lines += [
            "",
            "### Throughput: local worker processes",
            "",
            f"{tp['cases']} paper-sized joins (the six samples with jitter), "
            "`ProcessPoolExecutor` with the spawn context, one BLAS thread per worker, "
            "workers started and warmed before timing; "
            f"{tp.get('rounds', 1)} rounds, each timing the batch on both pools back to back "
            "(medians below).",
            "",
            "| workers | wall (s) | joins / s | median join in worker (ms) |",
            "|---:|---:|---:|---:|",
        ]
        for w in ("1", "2"):
            t = tp[w]
            lines.append(
                f"| {w} | {t['wall_seconds']:.2f} | {t['cases_per_second']:.1f} | "
                f"{_ms(t['median_case_seconds'])} |"
            )
        rounds = ", ".join(f"{x:.2f}" for x in tp.get("round_scalings", []))
        lines.append(
            f"\nScaling 2 vs 1 workers: **{tp['scaling']:.2f}×**"
            + (f" (median of the rounds: {rounds})." if rounds else ".")
        )
    paper = [c for c in cases if c["spec"]["kind"] == "paper"]
    if paper:
        lines += [
            "",
            f"Median full join over the six paper samples: "
            f"**{_ms(statistics.median(c['join_seconds'] for c in paper))} ms**.",
        ]
    lines += _resolve_table(cases)
    lines += _host_table(cases)
    lines += _iteration_table(cases)
    lines += _newton_table(cases)
    lines += _twolevel_table(cases)
    lines += _floor_table(cases)
    return "\n".join(lines) + "\n"


#: Time targets, milliseconds, by case kind: (full join, re-solve through a JoinSolver)
TARGETS_MS = {
    "paper": (30.0, 10.0),
    "host": (500.0, None),
    100_000: (3000.0, None),
    1_000_000: (60000.0, None),
}


def _target(case: dict):
    spec = case["spec"]
    if spec["kind"] in ("paper", "host"):
        return TARGETS_MS[spec["kind"]]
    return TARGETS_MS.get(spec.get("vertices"))


def _floor_table(cases: list[dict]) -> list[str]:
    """Targets beside the part of the time no local-step speed-up can remove.

    A local/global join that factors once spends at least the factorization
    plus one back-substitution per iteration; with our iteration counts that
    sum is shown for every case that has a target, and beside it what is spent
    before the first iteration (the set-up and the factorization).
    """
    rows = [c for c in cases if _target(c)]
    if not rows:
        return []
    lines = [
        "",
        "### Targets and the factor + back-solve floor",
        "",
        "*factor + back-solves*: the factorization and the back-substitutions at our "
        "iteration count, the part of the join that a faster local step cannot remove "
        "(docs/limits.md, *Speed*). *before the first iteration*: *setup* (above) plus the "
        "factorization.",
        "",
        "| case | iterations | join goal (ms) | join (ms) | re-solve goal (ms) "
        "| re-solve cold / warm (ms) | before the first iteration (ms) "
        "| factor + back-solves (ms) | local steps (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in rows:
        p = c["phases_raw"]
        goal, again = (None if t is None else t * 1e-3 for t in _target(c))
        r = c.get("resolve")
        resolved = "—" if not r else f"{_ms(r['cold_seconds'])} / {_ms(r['warm_seconds'])}"
        lines.append(
            f"| {c['name']} | {c['iterations']} | {_ms(goal)} | {_ms(c['join_seconds'])} | "
            f"{_ms(again)} | {resolved} | {_ms(c['phases']['setup'] + p['factor'])} | "
            f"{_ms(p['factor'] + p['back_solve'])} | "
            f"{_ms(p['local'])} |"
        )
    return lines


def _resolve_table(cases: list[dict]) -> list[str]:
    rows = [c for c in cases if c.get("resolve")]
    if not rows:
        return []
    lines = [
        "",
        "### Re-solves through one JoinSolver (the factorization reused)",
        "",
        "The seam targets turned by 1°, 2°, ... about an axis through their centroid (a "
        "slider), one `solve(targets)` per step from the initial guess (*cold*) and one "
        "`solve(targets, start=previous)` (*warm*); medians, milliseconds, whole `solve()` "
        "including the result's metrics. *factorizations*: made during all the re-solves. "
        "*gap*: largest (E_warm − E_cold) / E_cold.",
        "",
        "| case | cold (ms) | cold iterations | warm (ms) | warm iterations | factorizations "
        "| gap |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for c in rows:
        r = c["resolve"]
        lines.append(
            f"| {c['name']} | {_ms(r['cold_seconds'])} | "
            f"{statistics.median(r['cold_iterations']):.0f} | {_ms(r['warm_seconds'])} | "
            f"{statistics.median(r['warm_iterations']):.0f} | {r['factorizations']} | "
            f"{r['max_warm_cold_gap']:.1e} |"
        )
    paper = [c for c in rows if c["spec"]["kind"] == "paper"]
    if paper:
        cold = statistics.median(c["resolve"]["cold_seconds"] for c in paper)
        warm = statistics.median(c["resolve"]["warm_seconds"] for c in paper)
        lines.append(
            f"\nMedian re-solve over the six paper samples: **{_ms(cold)} ms** cold, "
            f"**{_ms(warm)} ms** warm."
        )
    return lines


def _host_table(cases: list[dict]) -> list[str]:
    rows = [c for c in cases if c["spec"]["kind"] == "host"]
    if not rows:
        return []
    lines = [
        "",
        "### A large host with a paper-sized guest",
        "",
        "The paper's partial-patch guest on a 350° aortic wall 300 mm long with the same "
        "hole (`pipelines/benchmark.py`, `_BIG_HOST`). *first*: the first join in the "
        "process (nothing cached); *join*: median of the timed runs; *setup* includes "
        "checking the host near its curve and selecting the curve; *whole host checked*: "
        "median of 3 joins in the same process with the whole host checked and its curve "
        "selected among all its loops (the path of a small host).",
        "",
        "| case | host vertices | host faces | guest vertices | first join (ms) | join (ms) "
        "| setup | iterate | metrics | whole host checked (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in rows:
        p = c["phases_raw"]
        lines.append(
            f"| {c['name']} | {c['host_vertices']:,} | {c['host_faces']:,} | "
            f"{c['counts']['points']:,} | {_ms(c.get('first_join_seconds'))} | "
            f"{_ms(c['join_seconds'])} | {_ms(c['phases']['setup'])} | {_ms(p['iterate'])} | "
            f"{_ms(p['metrics'])} | {_ms(c.get('whole_host_join_seconds'))} |"
        )
    return lines


def _iteration_table(cases: list[dict]) -> list[str]:
    """Iterations to convergence by guest size: plain local/global, accelerated, warm re-solve."""
    rows = [
        c
        for c in cases
        if (c["spec"]["kind"] == "paper" and c["spec"]["length"] == "equal")
        or c["spec"]["kind"] in ("patch", "tube")
    ]
    if not rows:
        return []
    lines = [
        "",
        "### Iterations by guest size",
        "",
        "*plain*: the paper's local/global iteration (`acceleration=0`) to "
        "`energy_tolerance=1e-12` where affordable; *accelerated*: the solver igljoin uses "
        "(L-BFGS with the default preconditioner and tolerance); *warm re-solve*: "
        "after a 1° slider step.",
        "",
        "| case | guest vertices | plain | accelerated | warm re-solve |",
        "|---|---:|---:|---:|---:|",
    ]
    for c in rows:
        p = c.get("plain")
        plain = "—" if not p else f"{p['iterations']}" + ("" if p["converged"] else " (cap)")
        its = str(c["iterations"]) + ("" if c["converged"] else " (time limit)")
        r = c.get("resolve")
        warm = "—" if not r else f"{statistics.median(r['warm_iterations']):.0f}"
        lines.append(f"| {c['name']} | {c['counts']['points']:,} | {plain} | {its} | {warm} |")
    return lines


def _newton_table(cases: list[dict]) -> list[str]:
    """Iterations of L-BFGS on ``P`` against L-BFGS on the Gauss–Newton model, side by side."""
    rows = [c for c in cases if c.get("newton") or c["spec"]["kind"] in ("patch", "tube")]
    if not any(c.get("newton") for c in rows):
        return []
    lines = [
        "",
        "### Iterations: the factored P against the Gauss–Newton model",
        "",
        "The same join from the same start with the initial Hessian of the quasi-Newton "
        "iteration replaced by the Gauss–Newton model with the rotations eliminated "
        "(`igljoin.newton`, assembled and factored once, 3n × 3n). *gap*: its final energy "
        "against the join's, relative (negative: lower). *assemble + factor*: the model's "
        "cost, on top of the iteration. — : not run (its factorization grows too fast; "
        "docs/limits.md).",
        "",
        "| case | guest vertices | iterations, P | iterations, Gauss–Newton | join (ms) "
        "| Gauss–Newton iteration (ms) | of which assemble + factor | gap |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in rows:
        g = c.get("newton")
        if g:
            its = str(g["iterations"]) + ("" if g["converged"] else " (cap)")
            cells = (
                f"{its} | {_ms(c['join_seconds'])} | {_ms(g['seconds'])} | "
                f"{_ms(g['assemble_seconds'] + g['factor_seconds'])} | "
                f"{g['relative_gap']:.1e}"
            )
        else:
            cells = f"— | {_ms(c['join_seconds'])} | — | — | —"
        lines.append(f"| {c['name']} | {c['counts']['points']:,} | {c['iterations']} | {cells} |")
    return lines


def _twolevel_table(cases: list[dict]) -> list[str]:
    """Iterations of the three ``preconditioner`` options, side by side."""
    rows = [c for c in cases if c.get("twolevel")]
    if not rows:
        return []
    lines = [
        "",
        "### Iterations: the factored P against the two-level preconditioner",
        "",
        "The same join from the same start, re-solved with each `preconditioner` option "
        "(the factorization reused). *factored*: `P⁻¹` alone; *two-level*: `P⁻¹` plus the "
        "Gauss–Newton model on the six rigid motions of clusters of about 20 free vertices, "
        "built at the start (`igljoin.twolevel`, additive form); *auto*: `P` below "
        "`igljoin.twolevel.AUTO_FROM_VERTICES` free vertices, from there rigid and three "
        "bending motions per cluster, rebuilt at the current iterate whenever a vertex's "
        "rotation has turned 0.2 rad (*builds*). *ms*: the iteration including the coarse "
        "set-up and rebuilds. *gap*: final energy against the factored run's, relative "
        "(negative: lower).",
        "",
        "| case | guest vertices | iterations, factored | ms | iterations, two-level "
        "| ms | gap | iterations, auto | builds | ms | gap |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def its(t: dict) -> str:
        return str(t["iterations"]) + ("" if t["converged"] else " (cap)")

    for c in rows:
        p, two, auto = (c["twolevel"].get(k) for k in _PRECONDITIONERS)
        if p is None or two is None or auto is None:  # a record of an older run
            lines.append(f"| {c['name']} | {c['counts']['points']:,} |" + " — |" * 9)
            continue
        lines.append(
            f"| {c['name']} | {c['counts']['points']:,} | {its(p)} | {_ms(p['seconds'])} | "
            f"{its(two)} | {_ms(two['seconds'])} | {two['relative_gap']:.1e} | "
            f"{its(auto)} | {auto['builds']} | {_ms(auto['seconds'])} | "
            f"{auto['relative_gap']:.1e} |"
        )
    return lines


def _kind_rank(case: dict) -> tuple:
    """Position of a case in a full run: paper samples, the large host, guests by size."""
    spec = case["spec"]
    rank = {"paper": 0, "host": 1}.get(spec["kind"], 2)
    return (rank, spec.get("vertices", 0))


def _name(spec: dict) -> str:
    if spec["kind"] == "host":
        return "patch on large host"
    if spec["kind"] == "paper":
        return f"{spec['scenario']}/{spec['length']}"
    v = spec["vertices"]
    size = f"{v // 1000:,}k" if v < 10**6 else f"{v / 1e6:g}M"
    extra = "".join(f", {k}={v}" for k, v in spec.get("options", {}).items())
    return f"{'tube' if spec['kind'] == 'tube' else 'patch'} {size}{extra}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small run (a few minutes)")
    ap.add_argument("--million", action="store_true", help="also the 1M-vertex guest")
    ap.add_argument("--runs", type=int, help="timed runs per paper sample (default 7, quick 3)")
    ap.add_argument(
        "--plain-iterations",
        type=int,
        help="iteration cap of the long plain run (default 30000, quick 3000)",
    )
    ap.add_argument("--cases", type=int, help="throughput cases (default 20, quick 8)")
    ap.add_argument("--sizes", help="large guests, comma-separated vertex counts")
    ap.add_argument("--out", help="output folder (default docs/, quick: benchmark-quick/)")
    ap.add_argument(
        "--only",
        help="run only the cases of these kinds (comma-separated: paper, host, patch, tube) "
        "and replace them in the existing benchmarks.json",
    )
    ap.add_argument(
        "--tables",
        action="store_true",
        help="rewrite benchmarks.md's tables from the folder's benchmarks.json (no run)",
    )
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(run_case(json.loads(args.worker))))
        return 0
    runs = args.runs or (3 if args.quick else 7)
    plain = args.plain_iterations or (3000 if args.quick else 30000)
    n_cases = args.cases or (8 if args.quick else 20)
    if args.sizes:
        sizes = [int(float(v)) for v in args.sizes.split(",") if v]
    else:
        sizes = [10_000] if args.quick else [10_000, 100_000]
    if args.million:
        sizes.append(1_000_000)
    million_budget = 600.0  # seconds of iteration for the 1M guest (reported if it stops there)
    out_dir = Path(args.out) if args.out else ROOT / ("benchmark-quick" if args.quick else "docs")
    if args.tables:
        if not (out_dir / "benchmarks.json").is_file():
            sys.exit(f"--tables reads {out_dir / 'benchmarks.json'}, which does not exist")
        _write_tables(out_dir, json.loads((out_dir / "benchmarks.json").read_text()))
        return 0
    specs = [
        {
            "kind": "paper",
            "scenario": sc,
            "length": ln,
            "runs": runs,
            "plain_iterations": plain,
            "resolves": runs,
            "newton": True,
            "twolevel": True,
        }
        for sc, ln in SAMPLES
    ]
    specs.append({"kind": "host", "runs": runs, "arap_runs": 1})
    for v in sizes:
        big = v >= 100_000
        specs.append(
            {
                "kind": "tube" if v >= 1_000_000 else "patch",
                "vertices": v,
                "runs": 1 if big else 3,
                "arap_runs": 0 if v >= 1_000_000 else 1,
                "warmup": not big,
                "time_limit": million_budget if v >= 1_000_000 else None,
                # the long plain run is affordable up to ~10k vertices (minutes)
                "plain_iterations": plain if v <= 10_000 else None,
                # the Gauss–Newton model's 3n × 3n factorization took 7 s at 10k (17× the
                # scalar one); at 100k it would take minutes and gigabytes
                "newton": v <= 10_000,
                # each option's re-solve at 1M would be another ten minutes
                "twolevel": v < 1_000_000,
            }
        )
    results = {"machine": _machine(), "cases": []}
    kept_cases = []
    if args.only:
        kinds = set(args.only.split(","))
        specs = [sp for sp in specs if sp["kind"] in kinds]
        n_cases = 0
        if not (out_dir / "benchmarks.json").is_file():
            sys.exit(
                f"--only replaces cases in {out_dir / 'benchmarks.json'}, which does not exist: "
                "run the whole benchmark into that folder first, or give --out a folder that "
                "holds one"
            )
        previous = json.loads((out_dir / "benchmarks.json").read_text())
        kept_cases = [c for c in previous["cases"] if c["spec"]["kind"] not in kinds]
        results["throughput"] = previous.get("throughput")
        # one flat list of the earlier runs' machines (each without its own list), newest first
        results["machine"]["earlier_runs"] = _earlier_runs(previous["machine"])
    for spec in specs:
        name = _name(spec)
        print(f"{name} ...", end=" ", flush=True)
        c = _in_subprocess(spec, timeout=7200)
        c["name"] = name
        results["cases"].append(c)
        gap = c.get("plain", {}).get("relative_gap")
        print(
            f"join {_ms(c['join_seconds'])} ms, {c['iterations']} it, ARAP ratio "
            f"{_s(c.get('ratio_full'))}, peak {c['peak_rss_mb']:,.0f} MB"
            + (f", gap {gap:.1e}" if gap is not None else ""),
            flush=True,
        )
    if n_cases > 0:
        print("throughput ...", end=" ", flush=True)
        results["throughput"] = throughput(n_cases)
        print(f"{results['throughput']['scaling']:.2f}x", flush=True)
    if args.only:
        new_cases = results["cases"]
        results["cases"] = kept_cases
        for c in new_cases:
            # back where the full run puts it: before the first case of a later kind
            at = next(
                (i for i, k in enumerate(results["cases"]) if _kind_rank(k) > _kind_rank(c)),
                len(results["cases"]),
            )
            results["cases"].insert(at, c)
    results["machine"]["load_average_end"] = os.getloadavg()
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "benchmarks.json", json.dumps(results, indent=1))
    print(_write_tables(out_dir, results))
    return 0


def _write_tables(out_dir: Path, results: dict) -> str:
    """Write ``benchmarks.md``'s tables for ``results`` (its hand-written head kept)."""
    table = markdown(results)
    md = out_dir / "benchmarks.md"
    marker = "<!-- benchmark tables -->"
    if not md.exists():
        atomic_write_text(md, f"# Benchmarks\n\n{marker}\n\n" + table)
    elif marker in md.read_text():
        head = md.read_text().split(marker)[0]
        atomic_write_text(md, head + f"{marker}\n\n" + table)
    else:
        sys.exit(
            f"{md} has no '{marker}' line, so it was not written by this script: it is left "
            "as it is; give --out another folder, or add the line where the tables go"
        )
    return table


if __name__ == "__main__":
    sys.exit(main())
