"""Seed statistics: confidence intervals and whether a difference from the baseline is noise.

Why a test at all: with deterministic runs, the spread between seeds is the only noise left (the
seed varies texture, keyframe sampling, densification offsets and RANSAC), and it can be as large
as the differences between strategies. A table that prints two means without saying whether they
differ by more than that spread invites reading noise as an effect.

Welch's t-test (unequal variances) compares a row's per-seed values with the baseline's in the
same column; a cell is "within seed noise" when p >= ``ALPHA``. With fewer than two seeds on
either side there is no variance to test against, and nothing is claimed.
"""

from __future__ import annotations

import math
import statistics
import warnings
from collections.abc import Sequence

from scipy import stats

ALPHA = 0.05  # two-sided; p >= ALPHA marks a cell as within seed noise
CONFIDENCE = 0.95


def confidence_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float] | None:
    """Student-t interval for the mean of ``values``; None with fewer than two values."""
    n = len(values)
    if n < 2:
        return None
    mean = statistics.fmean(values)
    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * statistics.stdev(values) / math.sqrt(n)
    return mean - half, mean + half


def welch_p(a: Sequence[float], b: Sequence[float]) -> float | None:
    """Two-sided p-value of Welch's t-test for equal means; None with fewer than two values on a side.

    Two zero-variance samples (a deterministic metric such as a Gaussian count that did not move
    with the seed) are equal or not: p is 1 or 0, where scipy would return NaN.
    """
    if len(a) < 2 or len(b) < 2:
        return None
    if statistics.pvariance(a) == 0 and statistics.pvariance(b) == 0:
        return 1.0 if statistics.fmean(a) == statistics.fmean(b) else 0.0
    with warnings.catch_warnings():  # one zero-variance side is valid input; scipy warns about its moments
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def within_noise(p: float | None) -> bool:
    """True when a p-value says the difference cannot be told from seed noise."""
    return p is not None and p >= ALPHA
