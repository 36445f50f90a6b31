"""Statistics over seeds for ``compare``: intervals, paired and unpaired differences, power.

Only numbers, computed with ``scipy.stats``; ``compare`` turns them into tables. Every function
sorts its values first, so no figure depends on the order in which the seeds come (the sum of
floats does, in its last bit). Confidence 95%, two-sided, throughout.

With x_1..x_n the values of one configuration (one per seed), mean m, SD s (n - 1 in the
denominator) and t_q(k) the q-quantile of Student's t with k degrees of freedom:

- **mean and t-interval** (``t_interval``): m +- t_0.975(n-1) * s / sqrt(n); one value: the value
  alone, no interval.
- **paired difference** (``paired_difference``), for two configurations that share seeds: the
  differences d_i = a_i - b_i of the seeds both ran (a seed only one of them ran is left out),
  their mean m_d and t-interval as above; the exact sign-flip permutation p-value: under "no
  difference" each d_i is as likely to be -d_i, so p is the share of the 2^n sign vectors e with
  |mean(e_i d_i)| >= |m_d|, counting the observed one (``scipy.stats.permutation_test``'s
  one-sample, ``permutation_type='samples'``, two-sided test: exact up to ``EXACT_UP_TO`` pairs,
  computed here as one array of all sign vectors with scipy's rule for ties, and beyond that
  scipy's own on ``RANDOM_SIGN_FLIPS`` random sign vectors with a fixed seed); the effect size Cohen's
  d_z = m_d / s_d; and the number of seeds n at which a two-sided paired t-test at alpha 0.05
  would detect an effect of d_z with 80% power (``paired_seeds_for_power``).
- **Welch's difference** (``welch_difference``), for configurations that share fewer than two
  seeds (different algorithm families): m_a - m_b with Welch's interval
  (m_a - m_b) +- t_0.975(nu) * sqrt(s_a^2/n_a + s_b^2/n_b), nu the Welch-Satterthwaite degrees of
  freedom, and its p-value (``scipy.stats.ttest_ind(equal_var=False)``); the effect size Cohen's
  d = (m_a - m_b) / sqrt((s_a^2 + s_b^2) / 2) and the seeds per configuration at which a
  two-sided two-sample t-test would detect it with 80% power (``unpaired_seeds_for_power``).

Power (Cohen 1988): with critical value c = t_(1-alpha/2)(df) and noncentrality delta, the power
of the two-sided t-test is P(T' > c) + P(T' < -c), T' noncentral t(df, delta)
(``scipy.stats.nct``); paired: df = n - 1, delta = d_z sqrt(n); two samples of n each:
df = 2n - 2, delta = d sqrt(n / 2). The seeds needed is the smallest n >= 2 with power >= 80%:
``math.inf`` where the effect is 0 (no number of seeds detects it) or needs more than
``MAX_SEEDS``, None where the effect size is undefined (fewer than two values, or no spread).

**Position between fine-tuning and rehearsal** (``position``), where a baseline configuration
(rehearsal) sets a scale: with d_i and r_i a configuration's and rehearsal's paired differences from
fine-tuning on the seeds both were paired on, mean(d) / mean(r): 0 is fine-tuning, 1 rehearsal (the
ratio of the seed means' differences from fine-tuning). A point estimate, without an interval.

**Holm-Bonferroni** (``holm``), for a family of m outcomes tested together (a study's secondary
outcomes): with the p-values sorted, p_(1) <= ... <= p_(m), the adjusted p_(i) is the largest of
min(1, (m - j + 1) p_(j)) over j <= i; an outcome is detected at level alpha where its adjusted p
is below alpha, which holds the chance of any false detection in the family at alpha.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
ALPHA = 0.05
POWER = 0.8
EXACT_UP_TO = 16
"""The sign-flip p-value enumerates all 2^n sign vectors up to this many pairs (65,536 vectors);
beyond, it draws ``RANDOM_SIGN_FLIPS`` of them."""
RANDOM_SIGN_FLIPS = 2 ** 16
SIGN_FLIP_SEED = 0
MAX_SEEDS = 10 ** 9
"""Beyond this many seeds the power search gives up and says ``math.inf``."""


def _sorted(values: Iterable[float]) -> np.ndarray:
    """The values ascending: a float sum depends on the order of its terms, the seeds' must not."""
    return np.sort(np.asarray(list(values), dtype=float))


@dataclass(frozen=True)
class Interval:
    """A mean over ``n`` values with its 95% t-interval (``low``, ``high``: NaN for one value)."""

    mean: float
    low: float
    high: float
    n: int


def t_interval(values: Iterable[float], confidence: float = CONFIDENCE) -> Interval:
    """Mean and t-interval, m +- t_((1+confidence)/2)(n-1) * s / sqrt(n); no values: all NaN;
    one value: the value, no interval (NaN ends); equal values: [m, m]."""
    data = _sorted(values)
    if data.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    mean = float(np.mean(data))
    if data.size == 1:
        return Interval(mean, math.nan, math.nan, 1)
    if data[0] == data[-1]:  # no spread: scipy's interval of scale 0 is NaN
        return Interval(mean, mean, mean, int(data.size))
    low, high = stats.t.interval(confidence, data.size - 1, loc=mean, scale=stats.sem(data))
    return Interval(mean, float(low), float(high), int(data.size))


@dataclass(frozen=True)
class Difference:
    """A configuration minus its baseline, over seeds."""

    test: str
    """``paired`` (per seed, the seeds both ran) or ``Welch`` (means of independent seeds)."""
    mean: float
    """The mean of the paired differences, or the difference of the means."""
    low: float
    high: float
    """The 95% interval of ``mean`` (NaN where undefined: a single pair)."""
    p: float | None
    """Two-sided p-value: the sign-flip permutation test (paired) or Welch's t-test."""
    p_exact: bool
    """Whether ``p`` enumerated every sign vector (paired, up to ``EXACT_UP_TO`` pairs)."""
    effect: float | None
    """Cohen's d_z (paired) or Cohen's d (Welch); None where undefined."""
    seeds_for_power: float | None
    """Seeds (pairs, or per configuration for Welch) for 80% power at this effect: an int, inf or None."""
    n: int
    """Pairs (paired) or the configuration's seeds (Welch)."""
    n_baseline: int | None = None
    """Welch: the baseline's seeds."""
    seeds: tuple[Any, ...] = ()
    differences: tuple[float, ...] = ()
    """Paired: the seeds both ran, ascending, and the difference of each."""
    p_holm: float | None = None
    """``p`` adjusted by Holm-Bonferroni over the family it was tested in (``holm``), if any."""


def sign_flip_p(differences: Iterable[float]) -> tuple[float, bool]:
    """The two-sided sign-flip permutation p-value of the mean of ``differences`` and whether it
    is exact (all 2^n sign vectors: up to ``EXACT_UP_TO`` values)."""
    data = _sorted(differences)
    if data.size > EXACT_UP_TO:
        result = stats.permutation_test(
            (data,), lambda x, axis: np.mean(x, axis=axis), permutation_type="samples", vectorized=True,
            n_resamples=RANDOM_SIGN_FLIPS, alternative="two-sided", random_state=np.random.default_rng(SIGN_FLIP_SEED))
        return float(result.pvalue), False
    # scipy's exact test builds its 2^n sign vectors as Python tuples, which made compare spend
    # most of its time here; the same null distribution as one array, one entry per sign vector
    # (bit j of the entry's number flips value j), and scipy's p-value with its tolerance for ties.
    # Each null sum adds the values one by one in order, as scipy's mean over its strided batch
    # does: numpy's pairwise sum rounds some of them otherwise, and where the observed mean is 0
    # but for its rounding, the tolerance is too small to absorb that
    flips = (np.arange(2 ** data.size)[:, None] >> np.arange(data.size)) & 1
    null = np.zeros(2 ** data.size)
    for j, value in enumerate(data):
        null += np.where(flips[:, j] == 1, -value, value)
    null /= data.size
    observed = np.mean(data)
    tie = abs(np.finfo(float).eps * 100 * observed)
    less = np.count_nonzero(null <= observed + tie) / null.size
    greater = np.count_nonzero(null >= observed - tie) / null.size
    return float(min(1.0, 2 * min(less, greater))), True


def _power(effect: float, n: int, paired: bool) -> float:
    """Power of the two-sided t-test at ALPHA: paired on n pairs, or two samples of n each."""
    df = n - 1 if paired else 2 * n - 2
    delta = effect * math.sqrt(n if paired else n / 2)
    critical = stats.t.ppf(1 - ALPHA / 2, df)
    # the lower tail as the upper tail of -T' (nct(df, -delta)): nct.cdf is unstable there
    return float(stats.nct.sf(critical, df, delta) + stats.nct.sf(critical, df, -delta))


def _seeds_for_power(effect: float | None, paired: bool) -> float | None:
    """The smallest n >= 2 whose power reaches POWER (doubling, then bisection: power grows with n)."""
    if effect is None or math.isnan(effect):
        return None
    if effect == 0:
        return math.inf
    high = 2
    while _power(effect, high, paired) < POWER:
        if high > MAX_SEEDS:
            return math.inf
        high *= 2
    low = high // 2  # power(low) < POWER, or low == 1 (n starts at 2)
    while high - low > 1:
        middle = (low + high) // 2
        if _power(effect, middle, paired) >= POWER:
            high = middle
        else:
            low = middle
    return high


def paired_seeds_for_power(d_z: float | None) -> float | None:
    """Pairs at which a two-sided paired t-test at alpha 0.05 detects an effect d_z with 80% power
    (df = n - 1, noncentrality d_z sqrt(n)); inf for d_z = 0, None for None."""
    return _seeds_for_power(d_z, paired=True)


def unpaired_seeds_for_power(d: float | None) -> float | None:
    """Seeds per configuration at which a two-sided two-sample t-test at alpha 0.05 detects an
    effect d with 80% power (df = 2n - 2, noncentrality d sqrt(n/2)); inf for d = 0, None for None."""
    return _seeds_for_power(d, paired=False)


def seed_order(seed: Any) -> tuple[int, Any]:
    """A sort key for seeds: numbers numerically (2 before 10), then anything else by its text."""
    return (0, seed) if isinstance(seed, (int, float)) and not isinstance(seed, bool) else (1, str(seed))


def paired_difference(values: Mapping[Any, float], baseline: Mapping[Any, float]) -> Difference:
    """``values`` minus ``baseline``, both seed -> value, paired by seed over the seeds both have
    (at least one): mean difference with its t-interval, the sign-flip p-value, d_z and the pairs
    needed for 80% power (see the module docstring for the formulas)."""
    seeds = sorted(set(values) & set(baseline), key=seed_order)
    if not seeds:
        raise ValueError("no seed in common: use welch_difference")
    differences = [float(values[s]) - float(baseline[s]) for s in seeds]
    data = _sorted(differences)
    interval = t_interval(data)
    sd = float(np.std(data, ddof=1)) if data.size > 1 else math.nan
    d_z = interval.mean / sd if data.size > 1 and sd > 0 else None
    p, exact = sign_flip_p(data)
    return Difference("paired", interval.mean, interval.low, interval.high, p, exact, d_z,
                      paired_seeds_for_power(d_z), int(data.size), None, tuple(seeds), tuple(differences))


def welch_difference(values: Iterable[float], baseline: Iterable[float]) -> Difference:
    """mean(``values``) - mean(``baseline``) of independent samples, with Welch's 95% interval and
    p-value (``scipy.stats.ttest_ind(equal_var=False)``; NaN/None with fewer than two values on a
    side; equal values on both sides: [difference, difference], no p), Cohen's d over the average
    variance and the seeds per configuration for 80% power."""
    a, b = _sorted(values), _sorted(baseline)
    if a.size == 0 or b.size == 0:
        raise ValueError("a side without values")
    mean = float(np.mean(a)) - float(np.mean(b))
    low = high = math.nan
    p = effect = None
    if a.size > 1 and b.size > 1 and (a[0] == a[-1] and b[0] == b[-1]):
        low = high = mean  # no spread on either side: no test
    elif a.size > 1 and b.size > 1:
        result = stats.ttest_ind(a, b, equal_var=False)
        interval = result.confidence_interval(CONFIDENCE)
        low, high, p = float(interval.low), float(interval.high), float(result.pvalue)
        spread = math.sqrt((float(np.var(a, ddof=1)) + float(np.var(b, ddof=1))) / 2)
        effect = mean / spread
    return Difference("Welch", mean, low, high, p, False, effect, unpaired_seeds_for_power(effect),
                      int(a.size), int(b.size))


def difference(values: Mapping[Any, float], baseline: Mapping[Any, float], pairable: bool = True) -> Difference:
    """Paired where the runs are ``pairable`` by seed and the two share at least two seeds, else
    Welch over all of each (seed -> value)."""
    if pairable and len(set(values) & set(baseline)) >= 2:
        return paired_difference(values, baseline)
    return welch_difference(values.values(), baseline.values())


def position(row: Difference, scale: Difference) -> tuple[float | None, tuple[Any, ...]]:
    """Where ``row`` stands between fine-tuning (0) and ``scale``'s configuration (1), both paired
    differences from fine-tuning on one outcome: mean(row's) / mean(scale's) over the seeds both
    have, and those seeds (see the module docstring). None where either is not paired, fewer than
    two seeds are shared, or the scale's mean difference on them is 0 (no scale)."""
    if row.test != "paired" or scale.test != "paired":
        return None, ()
    mine, theirs = dict(zip(row.seeds, row.differences)), dict(zip(scale.seeds, scale.differences))
    seeds = tuple(sorted(set(mine) & set(theirs), key=seed_order))
    if len(seeds) < 2:
        return None, seeds
    across = float(np.mean(_sorted(theirs[s] for s in seeds)))
    if across == 0:
        return None, seeds
    return float(np.mean(_sorted(mine[s] for s in seeds))) / across, seeds


def holm(p_values: Iterable[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values, in the order given (see the module docstring)."""
    given = list(p_values)
    order = sorted(range(len(given)), key=lambda i: given[i])
    adjusted = [0.0] * len(given)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(given) - rank) * given[i]))
        adjusted[i] = running
    return adjusted
