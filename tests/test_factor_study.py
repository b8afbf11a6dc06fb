"""The factorization study behind igljoin.linsolve's choice (``pipelines/factor_study.py``).

Its figures come from running it; here only that every method it times
solves the system it factors, on a small real matrix.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import igljoin
from igljoin import phantoms

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipelines"))
import factor_study  # noqa: E402

#: The package each method needs beyond the core dependencies.
NEEDS = {
    "cholespy": ("cholespy",),
    "cholespy-nd": ("cholespy", "pymetis"),
    "cholespy-rcm": ("cholespy",),
    "splu-nd": ("pymetis",),
    "qdldl": ("qdldl",),
    "pypardiso": ("pypardiso",),
}


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    """The free-free block of the join's preconditioner on a small patch, via the study."""
    path = tmp_path_factory.mktemp("factor") / "patch"
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    js = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    fixed = js.solver.fixed
    # what build() saves, without its factorization stand-in
    sp.save_npz(path.with_suffix(".P.npz"), sp.csr_matrix(js.solver.P))
    np.save(path.with_suffix(".fixed.npy"), fixed)
    A = factor_study.load_free_block(path)
    np.testing.assert_array_equal(A.toarray(), js.solver.factor.Qff.toarray())
    return A


def _available(method: str) -> bool:
    if method.startswith("pardiso"):
        return "pardiso" in igljoin.linsolve.available_backends()
    return all(importlib.util.find_spec(name) is not None for name in NEEDS.get(method, ()))


@pytest.mark.parametrize("method", factor_study.METHODS)
def test_every_method_solves_the_system(system, method):
    if not _available(method):
        pytest.skip(f"{method}: its package is not installed")
    solve, _ = factor_study.factor(method, system)
    b = np.random.default_rng(0).standard_normal((system.shape[0], 3))
    x = solve(b)
    # 1e-10 relative residual: a direct solve of this well-conditioned SPD system
    # leaves rounding only (measured 1e-15 to 1e-13 from 1k to 1M vertices)
    assert np.linalg.norm(system @ x - b) <= 1e-10 * np.linalg.norm(b)


def test_iterations_follow_the_measured_counts():
    for size, count in factor_study.ITERATIONS.items():
        assert factor_study.iterations(size) == count
    assert 100 < factor_study.iterations(30_000) < 250


def test_the_table_reports_a_missing_package():
    rows = [{"method": "qdldl", "missing": "No module named 'qdldl'"}]
    assert "No module named 'qdldl'" in factor_study.markdown(rows)
