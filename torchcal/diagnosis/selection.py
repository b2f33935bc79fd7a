"""Selection policy: which candidate the pre-screen proposes, which ones are refitted, and
when a full refit is accepted.

Pre-screen (linearised, `rank` / `select`): significant by a deterministic part first (by
held-out RMS), then by a random part only; within a tier a simpler candidate the best
does not beat significantly per pose is preferred.

Refit (`shortlist`, `refit_decision`): the candidates significant in the pre-screen (its
F-test or likelihood-ratio test at the Bonferroni-corrected level, and its 2 % held-out
gain), the pre-screen's verdict first, `REFITS` at most, are refitted in full
(torchcal.diagnosis.step). The pre-screen's significance controls the family-wise error
of the whole loop (alpha spending over rounds); the refit checks that the model itself,
refitted, predicts better: its held-out error must drop beyond chance. Per pose p,
``d_p = e0_p - e1_p``, the held-out squared distance error of the current model minus
the candidate's (both refitted on the same folds); a one-sided paired t-test of
mean(d) > 0 over the poses, at level ``REFIT_ALPHA / R`` for R candidates refitted
(Bonferroni over the refits of one step), and a relative held-out RMS gain of at least
`MIN_GAIN`. A candidate significant in the pre-screen by its random part only (a
variance term, which no deterministic refit can show) is accepted when its refit CV is
not worse than the current model's by more than `MIN_GAIN` (its deterministic part may
cost a little). A candidate that passes must also be determined by the data
(torchcal.diagnosis.step). Of those that pass, the one with the largest refit gain
(lowest refit CV RMS) is the step's verdict, whatever its place in the shortlist, unless
a simpler one that passed is not beaten by it significantly per pose (`not_better` on
the refits' held-out squared errors); a random-only term only when no deterministic
candidate passes (then in shortlist order).
"""

from __future__ import annotations

import numpy as np

from torchcal.diagnosis.candidates import Candidate
from torchcal.statistics import t_sf

ALPHA = 1e-3
MIN_GAIN = 0.02
MIN_LL_GAIN = 0.15  # nats per pose, for a variance (random clearance) term: the Gaussian
# model of a disc-shaped random tilt is misspecified, which alone is worth ~0.06
REFITS = 3  # candidates refitted in full per step
REFIT_ALPHA = 0.05  # family-wise level of the refit tests of one step


def not_better(best, c, attr: str, sign: float) -> bool:
    """True when `best` does not beat `c` significantly per pose: the paired difference of
    the per-pose held-out values (sign * (best - c), positive = best better) has a mean
    below two standard errors."""
    diff = sign * (getattr(best, attr) - getattr(c, attr))
    return diff.mean() < 2 * diff.std(ddof=1) / np.sqrt(len(diff))


def rank(cands: list) -> list:
    """Candidates best first: those significant by a deterministic part, by held-out RMS;
    then those significant by a random part only, by score; then the rest, by score."""
    return sorted(cands, key=lambda c: (0, c.cv_rms_mm) if c.deterministic else
                  (1, -c.score) if c.significant else (2, -c.score))


def select(cands: list) -> Candidate | None:
    """The verdict among ranked candidates, or None.

    A predictable (deterministic) explanation comes first: a random-only term (random
    clearance as a variance) can also soak up structure that some deterministic effect
    predicts, so it is named only when no deterministic candidate is significant.
    Within a tier, a simpler candidate (fewer new parameters) that the best does not beat
    significantly per pose is preferred (held-out squared error for deterministic terms,
    log-likelihood for random ones): e.g. an encoder-scale error over a limited joint
    range is fitted about as well by four harmonics, and the one-parameter effect is named.
    """
    det = [c for c in cands if c.deterministic]
    tier = det or [c for c in cands if c.significant]
    if not tier:
        return None
    best = tier[0]
    attr, sign = ("held_out_sq", -1.0) if det else ("held_out_ll", 1.0)
    close = [c for c in tier[1:] if c.k < best.k and not_better(best, c, attr, sign)]
    return min(close, key=lambda c: (c.k, tier.index(c)), default=best)


def shortlist(ranked: list, verdict: Candidate | None, refits: int = REFITS) -> list:
    """The candidates to refit in full (`Candidate`s, at most `refits`): the pre-screen's
    verdict first, then the other ranked candidates significant in the pre-screen."""
    out = [] if verdict is None or refits < 1 else [verdict]
    for c in ranked:
        if len(out) >= refits:
            break
        if c.significant and all(c.spec != o.spec for o in out):
            out.append(c)
    return out


def paired_p_value(base_sq: np.ndarray, cand_sq: np.ndarray) -> float:
    """One-sided p-value of mean(base_sq - cand_sq) > 0 over poses (paired t-test);
    base_sq, cand_sq (P,) per-pose held-out squared errors, mm^2. 1.0 when the
    differences have no spread and no positive mean, or are not finite."""
    d = base_sq - cand_sq
    if not np.all(np.isfinite(d)) or len(d) < 2:
        return 1.0
    se = d.std(ddof=1) / np.sqrt(len(d))
    if se == 0:
        return 0.0 if d.mean() > 0 else 1.0
    return t_sf(d.mean() / se, len(d) - 1)


def refit_decision(base_cv: float, base_sq: np.ndarray, cv: float, sq: np.ndarray, *, n_refits: int,
                   alpha: float, min_gain: float = MIN_GAIN, random_only: bool = False) -> tuple[bool, float, str]:
    """(accepted, p-value, reason) for one refitted candidate (module doc): level
    alpha / n_refits (Bonferroni over the candidates refitted in this step; alpha is
    `REFIT_ALPHA` in `diagnose`)."""
    p = paired_p_value(base_sq, sq)
    level = alpha / max(n_refits, 1)
    gain = (base_cv - cv) / max(base_cv, 1e-300)
    figures = f"refit cv {cv:.4f} mm vs {base_cv:.4f} mm"
    if not np.isfinite(cv):
        return False, p, "refit failed"
    if random_only:  # its deterministic part may cost a little: the gain rule's tolerance
        if cv <= base_cv * (1 + min_gain):
            return True, p, f"{figures}: random part significant, refit not worse by {100 * min_gain:g} %"
        return False, p, f"{figures}: random part only, and its refit is worse by more than {100 * min_gain:g} %"
    if cv >= base_cv:
        return False, p, f"{figures}: no gain (>=)"
    if p >= level:
        return False, p, f"{figures}: gain not beyond chance (p {p:.2g} >= {level:.2g})"
    if gain < min_gain:
        return False, p, f"{figures}: gain {100 * gain:.1f} % < {100 * min_gain:g} %"
    return True, p, f"{figures}: gain {100 * gain:.1f} %, p {p:.2g} < {level:.2g}"
