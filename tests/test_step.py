"""The step's verdict among the refits that passed (torchcal.diagnosis.step.choose), as a
pure function of the refits' held-out figures: the largest refit gain wins whatever the
shortlist order, a simpler candidate that is not beaten per pose is preferred, a
random-only term only when no deterministic one passed."""

import numpy as np

from torchcal.diagnosis.crossval import RefitCV
from torchcal.diagnosis.step import Scored, choose


def _scored(spec, sq, k, passed=True, random_only=False):
    sq = np.asarray(sq, dtype=float)
    cv = RefitCV(float(np.sqrt(sq.mean())), sq)
    return Scored([spec], spec, cv.cv_rms_mm, cv.cv_rms_mm, cv=cv, passed=passed, random_only=random_only, k=k)


SQ = np.random.default_rng(0).gamma(2.0, 0.05, size=200)


def test_the_largest_refit_gain_wins_not_the_shortlist_order():
    a, b, c = _scored("a", SQ * 0.9, 2), _scored("b", SQ * 0.5, 2), _scored("c", SQ * 0.7, 2)
    assert choose([a, b, c]) is b and choose([c, b, a]) is b


def test_refits_that_did_not_pass_are_never_chosen():
    best = _scored("best", SQ * 0.1, 1, passed=False)
    ok = _scored("ok", SQ * 0.9, 1)
    assert choose([best, ok]) is ok
    assert choose([best]) is None and choose([]) is None


def test_a_simpler_refit_not_beaten_per_pose_is_preferred():
    rng = np.random.default_rng(1)
    d = rng.normal(0, 0.01, size=SQ.size)
    d = d - d.mean() + 0.5 * d.std(ddof=1) / np.sqrt(SQ.size)  # half a standard error better
    big = _scored("big", SQ * 0.8 - d, 6)
    small = _scored("small", SQ * 0.8, 2)
    assert choose([big, small]) is small
    much = _scored("much", SQ * 0.4, 6)  # beats the simpler one clearly
    assert choose([much, small]) is much


def test_a_random_only_term_only_when_no_deterministic_one_passed():
    r = _scored("random", SQ * 0.5, 1, random_only=True)
    d = _scored("det", SQ * 0.9, 1)
    assert choose([r, d]) is d
    r2 = _scored("random2", SQ * 0.3, 1, random_only=True)
    assert choose([r, r2]) is r  # in shortlist order
