"""The smooth join's band rows are guarded by size before their matrices are built."""

import pytest

import igljoin
import igljoin.bandfit
import igljoin.terms
from igljoin import phantoms
from igljoin.terms import SmoothJoinTerm, band_couplings


@pytest.fixture(scope="module", params=["end_to_end", "partial_patch"])
def band_rows(request):
    s = phantoms.paper_sample(request.param, "equal")
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    (term,) = [t for t in solver.solver.terms if isinstance(t, SmoothJoinTerm)]
    return s, term.K


def test_couplings_are_the_non_zeros_of_the_band_block(band_rows):
    _, K = band_rows
    exact = (K.T @ K).nnz
    # every vertex sampled: the count is the block's own
    assert band_couplings(K, samples=K.shape[1]) == exact
    # 64 sampled vertices of several hundred: measured 0.2-0.6 % off on both samples;
    # 5 % is still far below the factor of 12-30 of the rows' squared lengths
    assert band_couplings(K) == pytest.approx(exact, rel=0.05)


def test_a_band_too_large_is_refused_before_its_matrices(band_rows, monkeypatch):
    s, K = band_rows
    monkeypatch.setattr(igljoin.terms, "MAX_BAND_COUPLINGS", (K.T @ K).nnz // 2)
    with pytest.raises(igljoin.OptionsError, match="smooth_band=.*smooth_mode='robust'"):
        igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    # the way out the message names works under the same guard
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode="robust")
    assert res.converged


def test_a_band_fit_too_large_is_refused_before_its_arrays(band_rows, monkeypatch):
    s, _ = band_rows
    monkeypatch.setattr(igljoin.bandfit, "MAX_FIT_ENTRIES", 100)
    with pytest.raises(igljoin.OptionsError, match="smooth_band=.*MAX_FIT_ENTRIES"):
        igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)


def test_the_measures_band_fit_is_refused_before_the_solve(band_rows, monkeypatch):
    s, _ = band_rows
    monkeypatch.setattr(igljoin.bandfit, "MAX_FIT_ENTRIES", 100)
    # the robust rows fit no band: only the result's measures do, and they are made at set-up
    with pytest.raises(igljoin.OptionsError, match="MAX_FIT_ENTRIES"):
        igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode="robust")
