"""Generic statistics: Student's t quantile, a mean with its Student-t confidence
interval and the paired two-sided t-test (scipy.stats underneath), and the upper tails of
Student's t, F and chi-square the diagnosis tests with (`t_sf`, `f_sf`, `chi2_sf`).

`t_quantile` is torchcal's own (the regularized incomplete beta by its continued
fraction, then Newton's method): every fit writes Student-t intervals, and importing
scipy.special for its quantile costs 0.1 s of CPU, a tenth of a `torchcal fit`
(docs/performance.md). It agrees with scipy.stats.t.ppf to 1e-12 relative up to 1e5
degrees of freedom and to 1e-10 up to 1e7 (tests/test_statistics.py).
"""

from __future__ import annotations

import math
from statistics import NormalDist

import torch

__all__ = ["t_quantile", "mean_ci", "paired_comparison", "t_sf", "f_sf", "chi2_sf"]

_TINY = 1e-300


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of the regularized incomplete beta I_x(a, b) (modified
    Lentz); it converges fast for x < (a + 1) / (a + b + 2)."""
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, 1_000_000):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + num / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) <= 1e-15:
            return h
    raise ArithmeticError(f"incomplete beta: no convergence for a={a}, b={b}, x={x}")


def _log_beta_half(a: float) -> float:
    """log B(a, 1/2) = log Gamma(1/2) - log(Gamma(a + 1/2) / Gamma(a)); for a > 100 the
    ratio by its asymptotic series (the difference of two lgamma would lose digits)."""
    if a <= 100.0:
        ratio = math.lgamma(a + 0.5) - math.lgamma(a)
    else:
        ratio = 0.5 * math.log(a) - 1 / (8 * a) + 1 / (192 * a ** 3) - 1 / (640 * a ** 5) + 17 / (14336 * a ** 7)
    return 0.5 * math.log(math.pi) - ratio


def _two_sided_tail(t: float, dof: float, log_beta: float) -> float:
    """P(|T| > t) for Student's t with dof degrees of freedom: I_x(dof / 2, 1 / 2) with
    x = dof / (dof + t^2); log_beta = log B(dof / 2, 1 / 2)."""
    a, b = dof / 2.0, 0.5
    x, y = dof / (dof + t * t), t * t / (dof + t * t)  # y = 1 - x without cancellation
    front = math.exp(-a * math.log1p(t * t / dof) + b * math.log(y) - log_beta) if y > 0 else 0.0
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_fraction(a, b, x) / a
    return 1.0 - front * _beta_fraction(b, a, y) / b


def t_quantile(p: float, dof: float) -> float:
    """The p quantile of Student's t with dof > 0 degrees of freedom (scipy.stats.t.ppf),
    0 < p < 1: Newton's method on the exact distribution function from the normal
    quantile, kept inside a bracket (bisection where a step would leave it)."""
    if not 0.0 < p < 1.0 or not dof > 0.0:
        raise ValueError(f"t_quantile: needs 0 < p < 1 and dof > 0, got p={p}, dof={dof}")
    if p < 0.5:
        return -t_quantile(1.0 - p, dof)
    if p == 0.5:
        return 0.0
    tail = 2.0 * (1.0 - p)  # P(|T| > t) at the answer
    log_beta = _log_beta_half(dof / 2.0)
    lo, hi = 0.0, math.inf
    t = NormalDist().inv_cdf(p)
    for _ in range(200):
        f = _two_sided_tail(t, dof, log_beta) - tail  # decreasing in t
        lo, hi = (t, hi) if f > 0 else (lo, t)
        density = math.exp(-log_beta - 0.5 * math.log(dof) - 0.5 * (dof + 1.0) * math.log1p(t * t / dof))
        new = t + f / (2.0 * density)
        if not lo < new < hi:
            new = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * t
        if abs(new - t) <= 1e-15 * new:
            return new
        t = new
    return t


# The upper tails by the scipy.special functions scipy.stats evaluates them with
# (t.sf: stdtr(dof, -x), f.sf: fdtrc, chi2.sf: chdtrc), with scipy.stats' handling of
# arguments outside the support and of bad degrees of freedom: the same float, bit for
# bit (tests/test_statistics.py). Importing scipy.stats costs 0.65 s of CPU and
# scipy.special 0.25 s (2-core development machine): `torchcal diagnose` and `discover`
# (and each process of `torchcal demo`) loaded scipy.stats for these three functions only.
def t_sf(x: float, dof: float) -> float:
    """P(T > x) for Student's t with `dof` degrees of freedom (scipy.stats.t.sf); nan when
    x is nan or dof is not positive."""
    from scipy.special import stdtr

    x = float(x)
    if math.isnan(x) or not dof > 0:
        return math.nan
    if math.isinf(x):
        return 0.0 if x > 0 else 1.0
    return float(stdtr(dof, -x))


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """P(F > x) for the F distribution with (dfn, dfd) degrees of freedom
    (scipy.stats.f.sf): 1 for x <= 0; nan when x is nan or a dof is not positive."""
    from scipy.special import fdtrc

    x = float(x)
    if math.isnan(x) or not (dfn > 0 and dfd > 0):
        return math.nan
    if x <= 0.0 or math.isinf(x):
        return 1.0 if x <= 0.0 else 0.0
    return float(fdtrc(dfn, dfd, x))


def chi2_sf(x: float, df: float) -> float:
    """P(X > x) for chi-square with `df` degrees of freedom (scipy.stats.chi2.sf): 1 for
    x <= 0; nan when x is nan or df is not positive."""
    from scipy.special import chdtrc

    x = float(x)
    if math.isnan(x) or not df > 0:
        return math.nan
    if x <= 0.0 or math.isinf(x):
        return 1.0 if x <= 0.0 else 0.0
    return float(chdtrc(df, x))


def mean_ci(values) -> dict:
    """{"mean", "ci95"}: the mean of the values and its 95 % Student-t confidence interval
    (None for a single value: no spread to estimate it from)."""
    v = torch.as_tensor(list(values), dtype=torch.float64)
    m = float(v.mean())
    if len(v) < 2:
        return {"mean": m, "ci95": None}
    h = t_quantile(0.975, len(v) - 1) * float(v.std(unbiased=True)) / math.sqrt(len(v))
    return {"mean": m, "ci95": [m - h, m + h]}


def paired_comparison(a, b, alpha: float = 0.05) -> dict:
    """Paired two-sided t-test of a - b (equal-length samples): mean difference, 95 % CI,
    p-value, significant (p < alpha). Identical samples give p = 1."""
    d = torch.as_tensor(list(a), dtype=torch.float64) - torch.as_tensor(list(b), dtype=torch.float64)
    out = mean_ci(d)
    if len(d) < 2 or float(d.std(unbiased=True)) == 0.0:
        p = 1.0 if float(d.abs().max()) == 0.0 or len(d) < 2 else 0.0
    else:
        import scipy.stats

        p = float(scipy.stats.ttest_1samp(d.numpy(), 0.0).pvalue)
    return {"diff_mm": out["mean"], "ci95": out["ci95"], "p": p, "significant": bool(p < alpha)}
