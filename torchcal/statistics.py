"""Generic statistics of repeated experiments: a mean with its Student-t confidence
interval and the paired two-sided t-test (scipy.stats underneath)."""

from __future__ import annotations

import math

import scipy.stats
import torch

__all__ = ["mean_ci", "paired_comparison"]


def mean_ci(values) -> dict:
    """{"mean", "ci95"}: the mean of the values and its 95 % Student-t confidence interval
    (None for a single value: no spread to estimate it from)."""
    v = torch.as_tensor(list(values), dtype=torch.float64)
    m = float(v.mean())
    if len(v) < 2:
        return {"mean": m, "ci95": None}
    h = float(scipy.stats.t.ppf(0.975, len(v) - 1) * v.std(unbiased=True) / math.sqrt(len(v)))
    return {"mean": m, "ci95": [m - h, m + h]}


def paired_comparison(a, b, alpha: float = 0.05) -> dict:
    """Paired two-sided t-test of a - b (equal-length samples): mean difference, 95 % CI,
    p-value, significant (p < alpha). Identical samples give p = 1."""
    d = torch.as_tensor(list(a), dtype=torch.float64) - torch.as_tensor(list(b), dtype=torch.float64)
    out = mean_ci(d)
    if len(d) < 2 or float(d.std(unbiased=True)) == 0.0:
        p = 1.0 if float(d.abs().max()) == 0.0 or len(d) < 2 else 0.0
    else:
        p = float(scipy.stats.ttest_1samp(d.numpy(), 0.0).pvalue)
    return {"diff_mm": out["mean"], "ci95": out["ci95"], "p": p, "significant": bool(p < alpha)}
