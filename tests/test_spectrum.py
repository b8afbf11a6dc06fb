"""The spectrum study behind docs/limits.md (``pipelines/spectrum.py``), at a small size."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipelines"))

import spectrum  # noqa: E402

import igljoin  # noqa: E402
from igljoin import phantoms  # noqa: E402


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("spectrum") / "spectrum.json"
    result = spectrum.main(["--resolution", "0.3", "--out", str(out)])
    return result, out


def test_writes_what_it_returns(study):
    result, out = study
    assert json.loads(out.read_text()) == json.loads(json.dumps(result))


def test_minimum_is_strict_and_p_is_stiffer_in_soft_modes(study):
    result, _ = study
    # a strict minimum: every generalized eigenvalue of (H, P) is positive
    assert result["P"]["min"] > 0 and result["Q"]["min"] > 0
    # soft modes exist: P overstates the stiffness of some modes at least tenfold
    assert result["P"]["min"] < 0.1 and result["P"]["condition"] > 10
    # ... but only a tail of them: P models most modes within a factor of about 3
    assert result["P"]["below"]["0.3"] < result["free_coordinates"] // 2


def test_oracle_without_correction_is_the_plain_join(study):
    result, _ = study
    # k = 0 wraps the back-solve without changing it: same iterations as the join itself
    assert result["oracle_iterations"]["0"] == result["iterations_default"]


def test_hessian_matches_a_directional_difference():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.3)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    X = solver.solve().guest.V
    H = spectrum.free_hessian(solver, X)
    ls = solver.solver
    free = ls.free
    rng = np.random.default_rng(3)
    v = rng.normal(size=(free.size, 3))
    h = 1e-6 * solver.guest_mean_edge

    def g(Y):
        return ls.local(Y)[2][free].reshape(-1)

    plus, minus = X.copy(), X.copy()
    plus[free] += h * v
    minus[free] -= h * v
    directional = (g(plus) - g(minus)) / (2.0 * h)
    # central differences of a smooth gradient: truncation O(h²) and rounding
    # O(eps·|g|/h) ~ 1e-7 relative at h = 1e-6 edge; 1e-4 leaves room for both
    assert np.abs(H @ v.reshape(-1) - directional).max() <= 1e-4 * np.abs(directional).max()
