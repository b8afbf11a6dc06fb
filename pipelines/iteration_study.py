"""What cuts the iteration count of the join? Three cheap candidates, measured.

Usage::

    python pipelines/iteration_study.py   # about 3 minutes; writes docs/iteration_study.json

1. **A longer quasi-Newton memory** (``acceleration`` = 10, 20, 40 pairs).
2. **Another preconditioner weight of the stretch term** (its
   ``preconditioner_scale``, 0.2 in igljoin; 0.05 to 0.35 here).
3. **A coarse-to-fine start.** The same phantom built with about a quarter
   of the guest vertices (an ideal coarse guest: the same geometry and seam,
   no decimation error) is joined first; its deformation is carried to the
   fine guest (closest point on the coarse rest surface, barycentric
   interpolation of the coarse deformed positions, the normal offset turned
   with the coarse face) and the fine join starts from there
   (``JoinSolver.solve(start=...)``). The fine iterations and the energy
   reached are compared with the fine join from its own initial guess.

Each study reports the iterations to convergence and the final energy, so
that a change that only stops earlier at a higher energy is visible.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import igl
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import igljoin  # noqa: E402
from igljoin import phantoms, terms  # noqa: E402
from igljoin.atomic import atomic_write_text  # noqa: E402

#: Guest vertices of the paper samples at guest_resolution 1 (end-to-end, partial patch).
_BASE = {"end_to_end": 2436, "partial_patch": 1305}

CASES = [
    ("end_to_end", "shorter"),
    ("end_to_end", "longer"),
    ("partial_patch", "equal"),
    ("partial_patch", "longer"),
]


def _sample(scenario: str, length: str, vertices: float | None = None):
    r = 1.0 if vertices is None else float(np.sqrt(vertices / _BASE[scenario]))
    return phantoms.paper_sample(scenario, length, guest_resolution=r)


def _join(s, **options):
    t0 = time.perf_counter()
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, **options)
    res = solver.solve()
    return solver, res, time.perf_counter() - t0


def memory_study() -> list[dict]:
    out = []
    for sc, ln in CASES:
        s = _sample(sc, ln)
        for m in (10, 20, 40):
            _, res, sec = _join(s, acceleration=m)
            out.append(
                {
                    "case": f"{sc}/{ln}",
                    "memory": m,
                    "iterations": res.iterations,
                    "energy": float(res.energy[-1]),
                    "seconds": sec,
                }
            )
    return out


def preconditioner_study() -> list[dict]:
    out = []
    kept = terms.StretchTerm.preconditioner_scale
    try:
        for scale in (0.05, 0.1, 0.2, 0.35):
            terms.StretchTerm.preconditioner_scale = scale
            for sc, ln in CASES:
                _, res, _ = _join(_sample(sc, ln))
                out.append(
                    {
                        "case": f"{sc}/{ln}",
                        "stretch_scale": scale,
                        "iterations": res.iterations,
                        "energy": float(res.energy[-1]),
                    }
                )
    finally:
        terms.StretchTerm.preconditioner_scale = kept
    return out


def carry(V0: np.ndarray, F: np.ndarray, X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Points ``P`` (k, 3) near the rest mesh ``(V0, F)`` moved with its deformation ``X``."""
    _, face, C = igl.point_mesh_squared_distance(P, V0, F)
    face = np.asarray(face, dtype=np.int64)
    A, B, D = (np.ascontiguousarray(V0[F[face, i]]) for i in range(3))
    L = igl.barycentric_coordinates(np.ascontiguousarray(C), A, B, D)
    XA, XB, XD = (X[F[face, i]] for i in range(3))
    moved = L[:, :1] * XA + L[:, 1:2] * XB + L[:, 2:3] * XD
    n0 = np.cross(B - A, D - A)
    n0 /= np.linalg.norm(n0, axis=1)[:, None]
    n1 = np.cross(XB - XA, XD - XA)
    n1 /= np.linalg.norm(n1, axis=1)[:, None]
    off = P - C
    h = np.einsum("ij,ij->i", off, n0)
    return moved + h[:, None] * n1 + (off - h[:, None] * n0)


def coarse_study(vertices: int = 10_000) -> list[dict]:
    out = []
    for sc, ln in (("partial_patch", "equal"), ("end_to_end", "equal")):
        fine = _sample(sc, ln, vertices)
        solver, res, sec = _join(fine)
        t0 = time.perf_counter()
        coarse_solver, coarse, _ = _join(_sample(sc, ln, vertices / 4))
        c = coarse_solver.corr
        start = carry(c.V, c.F, coarse.guest.V, solver.corr.V)
        t1 = time.perf_counter()
        again = solver.solve(start=start)
        t2 = time.perf_counter()
        out.append(
            {
                "case": f"{sc}/{ln}",
                "fine_vertices": int(len(res.guest.V)),
                "coarse_vertices": int(len(coarse.guest.V)),
                "fine_iterations": res.iterations,
                "fine_energy": float(res.energy[-1]),
                "fine_seconds": sec,
                "coarse_iterations": coarse.iterations,
                "coarse_seconds": t1 - t0,
                "from_coarse_iterations": again.iterations,
                "from_coarse_energy": float(again.energy[-1]),
                "from_coarse_seconds": t2 - t1,
            }
        )
    return out


def main() -> int:
    results = {}
    for name, study in (
        ("memory", memory_study),
        ("preconditioner", preconditioner_study),
        ("coarse_start", coarse_study),
    ):
        print(f"{name} ...", flush=True)
        results[name] = study()
        for row in results[name]:
            print("  ", row, flush=True)
    atomic_write_text(ROOT / "docs" / "iteration_study.json", json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
