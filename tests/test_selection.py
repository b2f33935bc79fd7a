"""discover's acceptance rules as pure functions (torchcal.diagnosis.selection), against
independent references: scipy's paired t-test, the Bonferroni level, the 2 % refit-gain
floor, the random-only rule, the per-pose 'not better' rule and the pre-screen's order."""

import math

import numpy as np
import pytest

from torchcal.diagnosis.candidates import Candidate
from torchcal.diagnosis.selection import (MIN_GAIN, REFIT_ALPHA, not_better, paired_p_value, rank, refit_decision,
                                          select, shortlist)


def _scaled(base, gain):
    """Per-pose squared errors whose held-out RMS is lower by `gain` on every pose."""
    return base * (1 - gain) ** 2


@pytest.fixture(scope="module")
def base():
    return np.random.default_rng(1).gamma(2.0, 0.05, size=300)


def test_refit_gain_floor_is_two_percent(base):
    """A clearly significant gain (every pose better) of 1.9 % is rejected, 2.1 % accepted."""
    assert MIN_GAIN == 0.02
    for gain, ok in ((0.019, False), (0.021, True)):
        cand = _scaled(base, gain)
        acc, p, why = refit_decision(math.sqrt(base.mean()), base, math.sqrt(cand.mean()), cand,
                                     n_refits=1, alpha=REFIT_ALPHA)
        assert p < 1e-10 and acc == ok, why
        if not ok:
            assert "gain 1.9 % < 2 %" in why


def test_paired_p_value_is_scipys_one_sided_paired_t_test(base):
    import scipy.stats
    rng = np.random.default_rng(2)
    cand = base - rng.normal(0.002, 0.01, size=base.size)
    ref = scipy.stats.ttest_rel(base, cand, alternative="greater").pvalue
    assert paired_p_value(base, cand) == pytest.approx(ref, rel=1e-10)
    assert paired_p_value(cand, base) == pytest.approx(1 - ref, rel=1e-10)


def test_multiple_testing_correction_splits_alpha_over_the_refits():
    """A paired gain with one-sided p between alpha / 3 and alpha: accepted when it is the
    only candidate refitted, rejected when three were (Bonferroni)."""
    rng = np.random.default_rng(0)
    base = rng.gamma(2.0, 0.05, size=200)
    d = rng.normal(0.0, 0.01, size=200)
    d = d - d.mean() + 2.4 * d.std(ddof=1) / math.sqrt(200)  # t = 2.4: p ~ 0.0087
    cand = base - d
    p = paired_p_value(base, cand)
    assert 0.01 / 3 < p < 0.01
    cv0, cv1 = math.sqrt(base.mean()), math.sqrt(cand.mean())
    assert refit_decision(cv0, base, cv1, cand, n_refits=1, alpha=0.01, min_gain=0.0)[0]
    ok, _, why = refit_decision(cv0, base, cv1, cand, n_refits=3, alpha=0.01, min_gain=0.0)
    assert not ok and "not beyond chance" in why


def test_no_gain_and_a_failed_refit_are_rejected(base):
    worse = _scaled(base, -0.05)
    ok, _, why = refit_decision(math.sqrt(base.mean()), base, math.sqrt(worse.mean()), worse, n_refits=1, alpha=0.05)
    assert not ok and "no gain (>=)" in why
    ok, _, why = refit_decision(math.sqrt(base.mean()), base, math.inf, base, n_refits=1, alpha=0.05)
    assert not ok and why == "refit failed"


def test_a_random_only_term_may_cost_up_to_the_floor(base):
    """Significant by its random part only: accepted while its refit CV is at most 2 %
    worse, whatever the paired test says."""
    cv0 = math.sqrt(base.mean())
    for worse, ok in ((0.019, True), (0.021, False)):
        cand = _scaled(base, -worse)
        assert refit_decision(cv0, base, math.sqrt(cand.mean()), cand, n_refits=1, alpha=0.05,
                              random_only=True)[0] == ok


def _cand(name, cv, k, sq=None, det=True, sig=True, score=0.0):
    return Candidate(name, (1,), 0.0, cv, score, 0.0, k, significant=sig, held_out_sq=sq, deterministic=det)


def test_not_better_is_a_two_standard_error_rule():
    """best beats c significantly per pose when the mean paired difference exceeds two
    standard errors (numpy reference)."""
    rng = np.random.default_rng(3)
    c_sq = rng.gamma(2.0, 0.05, size=100)
    noise = rng.normal(0, 0.01, size=100)
    for shift in (0.5, 1.5, 2.5, 3.5):
        d = noise - noise.mean() + shift * noise.std(ddof=1) / 10  # mean = shift standard errors
        best = _cand("best", 0.0, 2, sq=c_sq - d)
        c = _cand("c", 0.0, 1, sq=c_sq)
        assert not_better(best, c, "held_out_sq", -1.0) == (shift < 2), shift


def test_prescreen_order_and_shortlist():
    """Deterministic first by held-out RMS, then random-only by score, then the rest; the
    shortlist starts with the verdict and holds significant candidates only, three at most."""
    a, b = _cand("a", 0.30, 1), _cand("b", 0.20, 1)
    r = _cand("r", 0.10, 1, det=False, score=5.0)
    n = _cand("n", 0.05, 1, det=False, sig=False, score=9.0)
    ranked = rank([n, r, a, b])
    assert [c.effect for c in ranked] == ["b", "a", "r", "n"]
    assert [c.effect for c in shortlist(ranked, a)] == ["a", "b", "r"]
    assert [c.effect for c in shortlist(ranked, a, refits=2)] == ["a", "b"]
    assert shortlist(ranked, None, refits=0) == []


def test_select_prefers_a_simpler_candidate_the_best_does_not_beat():
    rng = np.random.default_rng(4)
    sq = rng.gamma(2.0, 0.05, size=100)
    d = rng.normal(0, 0.01, size=100)
    best = _cand("best", 0.20, 4, sq=sq - (d - d.mean() + 0.5 * d.std(ddof=1) / 10))  # 0.5 standard errors better
    simple = _cand("simple", 0.21, 1, sq=sq)
    clearly = _cand("clearly", 0.19, 4, sq=sq * 0.5)
    assert select(rank([best, simple])).effect == "simple"
    assert select(rank([clearly, simple])).effect == "clearly"
    assert select([_cand("x", 0.1, 1, det=False, sig=False)]) is None
