"""Which sparse factorization is fastest for the join's preconditioner at 10k-1M vertices?

Usage::

    python pipelines/factor_study.py                          # 10k and 100k guests
    python pipelines/factor_study.py --sizes 1e6 --methods cholespy,pardiso-1t
    python pipelines/factor_study.py --out factor-study/      # also writes factor_study.json

The matrix is the real one: ``P_ff``, the free-free block of the
preconditioner that :class:`igljoin.solve.LocalGlobalSolver` factors, of the
partial patch guest ``paper_sample("partial_patch", "equal",
guest_resolution=sqrt(n / 1180))`` (the 1M case: the end-to-end tube, as
``pipelines/benchmark.py`` builds it). The matrices are assembled once (the
factorization stubbed out) and cached as ``.npz`` in ``--cache``, named by a
hash of the package's source (matrices of other code are never reused).

Every (size, method) runs in its own subprocess, so that its peak memory
(``ru_maxrss``) is its own. Each reports the factor time (ordering,
analysis and numeric factorization, including any conversion of the
matrix), the median time of one 3-column back-solve (what each iteration
of the join does), the relative residual of that solve, and the peak
resident memory (and how much of it came after the matrix was loaded). A
join's factorization time is ``factor + iterations × back-solve``; the
table gives it with the iteration counts a join needs at each size (about
100 at 10k, 250 at 100k, 500 at 1M).

Methods (those whose package is missing are reported as such):

* ``igl`` — libigl's ``min_quad_with_fixed`` (Eigen's simplicial LDLᵀ).
* ``cholespy`` — what ``linear_solver="cholespy"`` does (CHOLMOD, simplicial,
  its own nested-dissection ordering, NESDIS).
* ``cholespy-nd`` / ``cholespy-rcm`` — the same on the matrix pre-permuted by
  METIS nested dissection (pymetis) / reverse Cuthill-McKee (scipy), to see
  whether CHOLMOD keeps the given order.
* ``splu`` — scipy's SuperLU (``MMD_AT_PLUS_A``, no pivoting, symmetric mode);
  ``splu-nd``: on the nested-dissection order with ``NATURAL``.
* ``qdldl`` — QDLDL (simplicial LDLᵀ with AMD).
* ``pardiso`` — what ``linear_solver="pardiso"`` does: MKL Pardiso through
  ctypes from the ``mkl`` wheel's ``libmkl_rt`` (real SPD, METIS ordering,
  MKL's own thread count), the back-solve its phase 33 with nothing else on
  the way; ``pardiso-1t``: the same on one thread.
* ``pypardiso`` — pypardiso's ``spsolve`` (its default unsymmetric type and
  per-call matrix hashing), for comparison.
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: Guest vertices per guest_resolution² (as pipelines/benchmark.py).
_PATCH_GUEST = 1180
_TUBE_GUEST = 2436

#: Iterations of a join at each size (docs/benchmarks.md: ~100 at 10k, ~250 at 100k, 500+ at
#: 1M); other sizes are interpolated in log(size).
ITERATIONS = {10_000: 100, 100_000: 250, 1_000_000: 500}


def iterations(size: int) -> int:
    """Iterations a join of ``size`` guest vertices needs (see :data:`ITERATIONS`)."""
    xs = np.log(list(ITERATIONS))
    return int(round(float(np.interp(np.log(size), xs, list(ITERATIONS.values())))))


METHODS = (
    "igl",
    "cholespy",
    "cholespy-nd",
    "cholespy-rcm",
    "splu",
    "splu-nd",
    "qdldl",
    "pardiso",
    "pardiso-1t",
    "pypardiso",
)


# -- the matrices --------------------------------------------------------------------------


def _sample(n: int):
    """The guest of about ``n`` vertices (the tube from 1M on, as pipelines/benchmark.py)."""
    from igljoin import phantoms

    if n >= 1_000_000:
        r = float(np.sqrt(n / _TUBE_GUEST))
        return phantoms.paper_sample("end_to_end", "equal", guest_resolution=r)
    r = float(np.sqrt(n / _PATCH_GUEST))
    return phantoms.paper_sample("partial_patch", "equal", guest_resolution=r)


class _Recorded:
    """Stand-in for FixedQuadratic that keeps the matrix and factors nothing."""

    made = 0

    def __init__(self, Q, fixed, backend="auto"):
        self.backend = "none"
        self.n = Q.shape[0]
        self.fixed = np.asarray(fixed, dtype=np.int64)
        mask = np.ones(self.n, dtype=bool)
        mask[self.fixed] = False
        self.free = np.flatnonzero(mask)


def build(n: int, path: Path, smooth_mode: str) -> dict:
    """Assemble the join's ``P`` and ``Q`` for a guest of about ``n`` vertices; save them."""
    import igljoin
    from igljoin import solve

    s = _sample(n)
    real = solve.FixedQuadratic
    solve.FixedQuadratic = _Recorded
    try:
        t0 = time.perf_counter()
        js = igljoin.JoinSolver(
            s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode=smooth_mode
        )
        seconds = time.perf_counter() - t0
    finally:
        solve.FixedQuadratic = real
    ls = js.solver
    P, Q = sp.csr_matrix(ls.P), sp.csr_matrix(ls.Q)
    sp.save_npz(path.with_suffix(".P.npz"), P)
    sp.save_npz(path.with_suffix(".Q.npz"), Q)
    np.save(path.with_suffix(".fixed.npy"), ls.fixed)
    return {"vertices": int(ls.n), "free": int(ls.n - len(ls.fixed)), "build_s": seconds}


def _code_digest() -> str:
    """Short hash of the package's source files (what builds ``P`` and ``Q``)."""
    digest = hashlib.sha256()
    for f in sorted((ROOT / "igljoin").rglob("*.py")):
        digest.update(f.read_bytes())
    return digest.hexdigest()[:12]


def load_free_block(path: Path, which: str = "P") -> sp.csr_matrix:
    M = sp.load_npz(path.with_suffix(f".{which}.npz")).tocsr()
    fixed = np.load(path.with_suffix(".fixed.npy"))
    mask = np.ones(M.shape[0], dtype=bool)
    mask[fixed] = False
    free = np.flatnonzero(mask)
    A = M[free][:, free].tocsr()
    A.sort_indices()
    return A


# -- the factorizations --------------------------------------------------------------------


def _nd_order(A: sp.csr_matrix) -> np.ndarray:
    import pymetis

    G = sp.csr_matrix(A, copy=True)
    G.setdiag(0)
    G.eliminate_zeros()
    graph = pymetis.CSRAdjacency(adj_starts=G.indptr, adjacent=G.indices)
    perm, _ = pymetis.nested_dissection(adjacency=graph)
    return np.asarray(perm, dtype=np.int64)


def _rcm_order(A: sp.csr_matrix) -> np.ndarray:
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    return np.asarray(reverse_cuthill_mckee(A, symmetric_mode=True), dtype=np.int64)


def _permuted(factor_solve, A, order):
    """Factor ``A[order][:, order]``; the returned solve maps back."""
    Ap = A[order][:, order].tocsc()
    Ap.sort_indices()
    solve = factor_solve(Ap)

    def s(b):
        x = np.empty_like(b)
        x[order] = solve(np.ascontiguousarray(b[order]))
        return x

    return s


def _cholespy(A):
    import cholespy

    C = sp.csc_matrix(A)
    C.sort_indices()
    ch = cholespy.CholeskySolverD(
        C.shape[0],
        C.indptr.astype(np.int32),
        C.indices.astype(np.int32),
        np.ascontiguousarray(C.data),
        cholespy.MatrixType.CSC,
    )

    def solve(b):
        x = np.empty_like(b)
        ch.solve(b, x)
        return x

    return solve


def _splu(A, permc="MMD_AT_PLUS_A"):
    from scipy.sparse.linalg import splu

    lu = splu(
        sp.csc_matrix(A),
        permc_spec=permc,
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    return lu.solve


def _qdldl(A):
    import qdldl

    f = qdldl.Solver(sp.csc_matrix(A))

    def solve(b):
        return np.column_stack([f.solve(np.ascontiguousarray(b[:, j])) for j in range(b.shape[1])])

    return solve


def _pypardiso(A):
    import pypardiso

    csr = sp.csr_matrix(A)
    pypardiso.spsolve(csr, np.ones((A.shape[0], 3)))  # factors

    def solve(b):
        return pypardiso.spsolve(csr, b)

    return solve


def _igl(A):
    import igl

    n = A.shape[0]
    data = igl.min_quad_with_fixed_data()
    ok = igl.min_quad_with_fixed_precompute(
        sp.csc_matrix(A), np.zeros(0, dtype=np.int64), sp.csc_matrix((0, n)), True, data
    )
    if ok is False:
        raise RuntimeError("libigl could not factor")

    def solve(b):
        z = np.zeros((0, b.shape[1]))
        return np.asarray(igl.min_quad_with_fixed_solve(data, -b, z, z))

    return solve


def factor(method: str, A: sp.csr_matrix):
    """Factor ``A`` with ``method``; returns (solve, extra info)."""
    info = {}
    if method == "igl":
        return _igl(A), info
    if method == "cholespy":
        return _cholespy(A), info
    if method == "cholespy-nd":
        return _permuted(_cholespy, A, _nd_order(A)), info
    if method == "cholespy-rcm":
        return _permuted(_cholespy, A, _rcm_order(A)), info
    if method == "splu":
        from scipy.sparse.linalg import splu  # noqa: F401 - import before timing ends

        lu_solve = _splu(A)
        return lu_solve, info
    if method == "splu-nd":
        return _permuted(lambda C: _splu(C, "NATURAL"), A, _nd_order(A)), info
    if method == "qdldl":
        return _qdldl(A), info
    if method.startswith("pardiso"):
        # igljoin's backend; pardiso-1t: MKL on one thread (default: MKL's own choice)
        from igljoin import linsolve

        lib, _ = linsolve._mkl_rt()
        if method == "pardiso-1t":
            lib.MKL_Set_Num_Threads(ctypes.c_int(1))
        info["mkl_threads"] = int(lib.MKL_Get_Max_Threads())
        f = linsolve._Pardiso(A)
        info["nnz_L"] = int(f.iparm[17])
        info["pardiso_peak_kb"] = int(max(f.iparm[14], f.iparm[15] + f.iparm[16]))
        return f.solve, info
    if method == "pypardiso":
        return _pypardiso(A), info
    raise ValueError(method)


def run_one(spec: dict) -> dict:
    """One (matrix, method) in this process: factor, back-solves, residual, memory."""
    path = Path(spec["path"])
    A = load_free_block(path, spec.get("which", "P"))
    n = A.shape[0]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t0 = time.perf_counter()
    try:
        solve, info = factor(spec["method"], A)
    except ImportError as exc:
        return {"method": spec["method"], "missing": str(exc)}
    t_factor = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    times, res = [], []
    for _ in range(spec["solves"]):
        b = rng.standard_normal((n, 3))
        t0 = time.perf_counter()
        x = solve(b)
        times.append(time.perf_counter() - t0)
        res.append(float(np.linalg.norm(A @ x - b) / np.linalg.norm(b)))
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {
        "method": spec["method"],
        "free": n,
        "nnz_A": int(A.nnz),
        "factor_s": t_factor,
        "solve3_s": statistics.median(times),
        "residual": max(res),
        "peak_rss_mb": rss1,
        "rss_after_load_mb": rss0,
        **info,
    }


# -- driver --------------------------------------------------------------------------------


def _subprocess(args: list[str], timeout: float) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), *args]
    env = dict(os.environ)
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT
        )
    except subprocess.TimeoutExpired:
        # one slow case is a row of the table, not the end of the study
        return {"error": f"timed out after {timeout:g} s"}
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "?"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def markdown(rows: list[dict]) -> str:
    lines = [
        "| free vertices | method | factor s | 3-col back-solve ms | join share s "
        "(factor + it x solve) | peak RSS MB (after load) | residual |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "factor_s" not in r:
            why = r.get("missing") or r.get("error", "?")
            lines.append(f"| {r.get('free', '')} | {r['method']} | — | — | — | — | {why} |")
            continue
        it = r["iterations"]
        total = r["factor_s"] + it * r["solve3_s"]
        lines.append(
            f"| {r['free']:,} | {r['method']} | {r['factor_s']:.2f} | {1e3 * r['solve3_s']:.1f} "
            f"| {total:.1f} ({it} it) | {r['peak_rss_mb']:.0f} ({r['rss_after_load_mb']:.0f}) "
            f"| {r['residual']:.0e} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1e4,1e5", help="guest vertex counts, comma-separated")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated")
    ap.add_argument(
        "--smooth-mode",
        default="band",
        choices=("band", "robust", "paper"),
        help="the join's smooth_mode (band, the default, makes P much denser near the seam)",
    )
    ap.add_argument("--which", default="P", choices=("P", "Q"), help="matrix to factor")
    ap.add_argument("--cache", default=os.path.join("/tmp", "igljoin-factor-study"))
    ap.add_argument("--out", help="folder for factor_study.json and .md")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per case")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--build", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(run_one(json.loads(args.worker))))
        return 0
    if args.build:
        spec = json.loads(args.build)
        print(json.dumps(build(spec["n"], Path(spec["path"]), spec["smooth_mode"])))
        return 0
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in (int(float(v)) for v in args.sizes.split(",") if v):
        # named by the package's code, so a matrix saved by other code is never timed
        path = cache / f"guest{size}-{args.smooth_mode}-{_code_digest()}"
        if not path.with_suffix(".fixed.npy").exists():
            job = {"n": size, "path": str(path), "smooth_mode": args.smooth_mode}
            built = _subprocess(["--build", json.dumps(job)], 3600)
            print(f"built {size}: {built}", file=sys.stderr)
        it = iterations(size)
        solves = 20 if size <= 20_000 else (10 if size <= 200_000 else 5)
        for method in args.methods.split(","):
            spec = {"path": str(path), "method": method, "solves": solves, "which": args.which}
            r = _subprocess(["--worker", json.dumps(spec)], args.timeout)
            r.setdefault("method", method)
            r["size"], r["iterations"], r["smooth_mode"] = size, it, args.smooth_mode
            rows.append(r)
            print(json.dumps(r), file=sys.stderr, flush=True)
    table = markdown(rows)
    print(table)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "factor_study.json").write_text(json.dumps(rows, indent=1) + "\n")
        (out / "factor_study.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
