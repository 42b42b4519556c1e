"""The statistics every steering table reports: mean +- standard error over seeds, Wilson
intervals on pooled episodes and McNemar's exact test on paired ones, as numbers and in the one
text form the tables share.

It sits below every other module of :mod:`equigym.steer` and :mod:`equigym.study` (it imports
neither), so that the sweep report, the control-arm comparison and the study report format a
figure the same way.
"""

from __future__ import annotations

import math

from equigym import _core


def mean_se(xs: list[float]) -> tuple[float, float]:
    """Mean and standard error (sample standard deviation / sqrt(n)) of ``xs``; nan where there
    are too few values (no mean without a value, no error without two)."""
    if not xs:
        return math.nan, math.nan
    m = sum(xs) / len(xs)
    if len(xs) < 2:
        return m, math.nan
    return m, math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1) / len(xs))


def format_mean_se(xs: list[float], digits: int = 3, count: bool = False) -> str:
    """``mean +- s.e.`` of ``xs`` to ``digits`` decimals; one value alone; ``-`` without any;
    with ``count``, the number of values after it in parentheses."""
    m, se = mean_se(xs)
    if math.isnan(m):
        return "-"
    text = f"{m:.{digits}f}" + ("" if math.isnan(se) else f" +- {se:.{digits}f}")
    return text + (f" ({len(xs)})" if count else "")


def format_pooled(wins: int, n: int, counts: bool = True) -> str:
    """A success rate pooled over ``n`` episodes with its 95% Wilson interval,
    ``wins/n = rate [low, high]`` (without ``wins/n`` when ``counts`` is off); ``-`` without
    episodes."""
    if not n:
        return "-"
    low, high = _core.wilson(wins, n)
    return (f"{wins}/{n} = " if counts else "") + f"{wins / n:.3f} [{low:.3f}, {high:.3f}]"


def mcnemar_p(a_only: int, b_only: int) -> float:
    """McNemar's exact two-sided p for two arms run on the same starts: ``a_only`` starts succeed
    with the first arm only, ``b_only`` with the second only (the starts both win or both lose say
    nothing of the difference); 1 without a discordant start. Needs scipy (the ``train`` extra)."""
    from scipy.stats import binomtest

    n = a_only + b_only
    return float(binomtest(a_only, n, 0.5).pvalue) if n else 1.0
