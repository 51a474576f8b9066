"""Statistics of the intervention protocol: seed-level tests, effect sizes, intervals, power.

Steps of one episode are not independent (consecutive steps share the scene and the ego's state), so the
unit of replication is the *seed*: a condition's p-value is the one-sample t-test of its per-seed mean
differences against 0 (n = seeds). Effect sizes are reported two ways — Cohen's d over per-step
differences (mean / sd of the step differences, as the paper's Alpamayo tables) and over per-seed means —
always with the counts behind them. Many conditions are corrected with Holm's step-down method
(statsmodels ``multipletests``). Closed-loop intervals are t-intervals across seeds of per-seed
differences. Seed planning uses statsmodels' ``TTestPower``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

DEFAULT_THRESHOLD_M = 0.1
"""A step counts as shorter / longer when its difference exceeds this (metres), as in the paper's tables."""

DEFAULT_ALPHA = 0.05


def _finite_or_none(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def json_number(value: float | None) -> float | str | None:
    """A float for JSON: NaN → None, ±inf → "inf"/"-inf" (strict JSON has neither)."""
    if value is None or math.isnan(value):
        return None
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return float(value)


def from_json_number(value: Any) -> float:
    """The float :func:`json_number` wrote: None → NaN, "inf"/"-inf" → ±inf."""
    if value is None:
        return math.nan
    if value in ("inf", "-inf"):
        return math.inf if value == "inf" else -math.inf
    return float(value)


# -- elementary statistics --------------------------------------------------------------------------------
def has_no_spread(x: np.ndarray) -> bool:
    """All values equal up to floating-point rounding (relative 1e-9)."""
    scale = max(1.0, float(np.max(np.abs(x))))
    return float(np.ptp(x)) <= 1e-9 * scale


def cohens_d(values: Sequence[float]) -> float:
    """Mean / sample standard deviation (ddof = 1) of ``values``.

    0 when all are exactly 0 (the selfsplice control). NaN with fewer than two values, and NaN when the
    values are equal but not 0: an effect size has no meaning without spread (e.g. a deterministic model
    on a route the seed does not change gives the same number for every seed).
    """
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return math.nan
    if np.all(x == 0.0):
        return 0.0
    if has_no_spread(x):
        return math.nan
    return float(np.mean(x)) / float(np.std(x, ddof=1))


@dataclass(frozen=True)
class TTest:
    """A one-sample t-test against 0: statistic, two-sided p-value, degrees of freedom."""

    t: float
    p: float
    df: int


def one_sample_t_test(values: Sequence[float]) -> TTest:
    """Two-sided one-sample t-test of ``values`` against 0 (scipy), with the degenerate cases defined.

    All values exactly 0 (e.g. selfsplice) → t = 0, p = 1. Fewer than two values → NaN. Values equal up
    to rounding but not 0 → NaN too, not p = 0: seeds that all give the same number are not independent
    replications (the seed changed nothing), so they carry no evidence a t-test could weigh.
    """
    from scipy import stats

    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return TTest(math.nan, math.nan, max(0, x.size - 1))
    if np.all(x == 0.0):
        return TTest(0.0, 1.0, x.size - 1)
    if has_no_spread(x):
        return TTest(math.nan, math.nan, x.size - 1)
    with warnings.catch_warnings():
        # nearly identical values (a strong, steady effect) make scipy warn about precision; p is ~0 then
        warnings.simplefilter("ignore", RuntimeWarning)
        result = stats.ttest_1samp(x, 0.0)
    return TTest(float(result.statistic), float(result.pvalue), x.size - 1)


@dataclass(frozen=True)
class Interval:
    """A mean with its two-sided confidence interval; ``low``/``high`` are NaN with fewer than two values."""

    mean: float
    low: float
    high: float
    n: int
    confidence: float = 0.95

    @property
    def excludes_zero(self) -> bool:
        return bool(self.low > 0.0 or self.high < 0.0)

    def to_json(self) -> dict[str, Any]:
        return {"mean": json_number(self.mean), "low": json_number(self.low), "high": json_number(self.high),
                "n": self.n, "confidence": self.confidence}


def t_interval(values: Sequence[float], confidence: float = 0.95) -> Interval:
    """Student-t interval of the mean of ``values``: mean ± t_{(1+c)/2, n−1} · sd / √n."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    n = int(x.size)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0, confidence)
    mean = float(np.mean(x))
    if n < 2:
        return Interval(mean, math.nan, math.nan, n, confidence)
    half = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * float(np.std(x, ddof=1)) / math.sqrt(n)
    return Interval(mean, mean - half, mean + half, n, confidence)


def holm_adjust(pvalues: Sequence[float], alpha: float = DEFAULT_ALPHA) -> tuple[list[float], list[bool]]:
    """Holm-adjusted p-values and rejections (statsmodels ``multipletests``); NaN p-values stay NaN."""
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(pvalues, dtype=float)
    adjusted = np.full(p.shape, math.nan)
    reject = np.zeros(p.shape, dtype=bool)
    ok = ~np.isnan(p)
    if ok.any():
        rej, corrected, _, _ = multipletests(p[ok], alpha=alpha, method="holm")
        adjusted[ok], reject[ok] = corrected, rej
    return [float(v) for v in adjusted], [bool(r) for r in reject]


# -- open loop ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OpenLoopStats:
    """One condition at one horizon: per-step differences vs selfsplice (metres), pooled over seeds.

    ``n`` steps over ``n_seeds`` seeds; ``mean_diff``/``sd_diff`` over steps; ``pct_shorter``/``pct_longer``
    the percentage of steps whose difference is below −``threshold`` / above +``threshold``; ``d_steps``
    Cohen's d over steps (mean / sd of the step differences); ``seed_means`` the per-seed mean differences;
    ``d_seeds`` Cohen's d over those; ``t``/``p`` the seed-level one-sample t-test (df = n_seeds − 1);
    ``p_holm``/``significant`` after Holm across the run's conditions (the control is not tested).
    """

    condition: str
    horizon_s: float
    n: int
    n_seeds: int
    mean_diff: float
    sd_diff: float
    pct_shorter: float
    pct_longer: float
    threshold: float
    d_steps: float
    seed_means: tuple[float, ...]
    d_seeds: float
    t: float
    p: float
    df: int
    p_holm: float = math.nan
    significant: bool = False
    intent: str = "none"

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        for key, value in data.items():
            if isinstance(value, float):
                data[key] = json_number(value)
        data["seed_means"] = [json_number(v) for v in self.seed_means]
        return data

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> OpenLoopStats:
        floats = {k: from_json_number(data[k]) for k in ("horizon_s", "mean_diff", "sd_diff", "pct_shorter",
                                                          "pct_longer", "threshold", "d_steps", "d_seeds", "t",
                                                          "p", "p_holm")}
        return cls(condition=data["condition"], n=int(data["n"]), n_seeds=int(data["n_seeds"]),
                   seed_means=tuple(from_json_number(v) for v in data["seed_means"]), df=int(data["df"]),
                   significant=bool(data["significant"]), intent=data.get("intent", "none"), **floats)


def open_loop_stats(condition: str, horizon_s: float, diffs_by_seed: Mapping[int, Sequence[float]],
                    threshold: float = DEFAULT_THRESHOLD_M, intent: str = "none") -> OpenLoopStats:
    """Summarise one condition's per-step differences (condition − selfsplice), grouped by seed."""
    groups = [np.asarray(diffs_by_seed[s], dtype=float) for s in sorted(diffs_by_seed)]
    groups = [g for g in groups if g.size]
    steps = np.concatenate(groups) if groups else np.zeros(0)
    n = int(steps.size)
    seed_means = tuple(float(np.mean(g)) for g in groups)
    test = one_sample_t_test(seed_means)
    return OpenLoopStats(
        condition=condition,
        horizon_s=float(horizon_s),
        n=n,
        n_seeds=len(groups),
        mean_diff=float(np.mean(steps)) if n else math.nan,
        sd_diff=float(np.std(steps, ddof=1)) if n > 1 else math.nan,
        pct_shorter=100.0 * float(np.mean(steps < -threshold)) if n else math.nan,
        pct_longer=100.0 * float(np.mean(steps > threshold)) if n else math.nan,
        threshold=float(threshold),
        d_steps=cohens_d(steps),
        seed_means=seed_means,
        d_seeds=cohens_d(seed_means),
        t=test.t,
        p=test.p,
        df=test.df,
        intent=intent,
    )


def with_holm(rows: Sequence[OpenLoopStats], alpha: float = DEFAULT_ALPHA,
              control: str = "selfsplice") -> list[OpenLoopStats]:
    """``rows`` of one horizon with Holm-adjusted p-values across every condition but the ``control``."""
    tested = [i for i, r in enumerate(rows) if r.condition != control]
    adjusted, reject = holm_adjust([rows[i].p for i in tested], alpha)
    out = list(rows)
    for i, p_holm, rej in zip(tested, adjusted, reject, strict=True):
        out[i] = replace(rows[i], p_holm=p_holm, significant=rej)
    return out


# -- closed loop --------------------------------------------------------------------------------------------
def cumulative_distance(times: Sequence[float], xy: Sequence[Sequence[float]],
                        checkpoints: Sequence[float]) -> list[float]:
    """Distance the ego travelled from the first step up to each checkpoint time (linear interpolation).

    After the episode's last step the distance stays at its final value (the episode ended: route
    complete, collision or timeout).
    """
    t = np.asarray(times, dtype=float)
    pts = np.asarray(xy, dtype=float).reshape(-1, 2)
    if t.size == 0:
        return [math.nan for _ in checkpoints]
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    rel = t - t[0]
    return [float(np.interp(c, rel, along)) for c in checkpoints]


@dataclass(frozen=True)
class EpisodeSummary:
    """What a closed-loop comparison needs from one episode log.

    ``brake_steps`` counts steps whose applied control braked; ``shadow_brake_steps`` counts steps where
    the controller would have braked under the model's own (un-injected) trajectory — the paper's *orig.
    brakes* (for a baseline episode the two are equal). ``route_completion`` ∈ [0, 1].
    """

    seed: int
    steps: int
    duration_s: float
    mean_speed: float
    route_completion: float
    completed: bool
    collided: bool
    brake_steps: int
    shadow_brake_steps: int
    distances: tuple[float, ...]
    terminal: str | None = None

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["distances"] = [json_number(v) for v in self.distances]
        return data

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> EpisodeSummary:
        fields = dict(data)
        fields["distances"] = tuple(from_json_number(v) for v in data["distances"])
        return cls(**fields)


@dataclass(frozen=True)
class ClosedLoopStats:
    """One condition's closed-loop episodes against the matched-seed baselines.

    ``distance_diff[i]`` is the t-interval across seeds of (condition − baseline) cumulative distance at
    ``checkpoints[i]``; the other fields are means across seeds (``completed``/``collisions`` are counts).
    """

    condition: str
    n_seeds: int
    checkpoints: tuple[float, ...]
    distance_diff: tuple[Interval, ...]
    shadow_brakes: float
    brakes: float
    steps: float
    mean_speed: float
    route_completion: float
    completed: int
    collisions: int
    intent: str = "none"

    def to_json(self) -> dict[str, Any]:
        return {
            "condition": self.condition, "n_seeds": self.n_seeds, "checkpoints": list(self.checkpoints),
            "distance_diff": [i.to_json() for i in self.distance_diff], "shadow_brakes": self.shadow_brakes,
            "brakes": self.brakes, "steps": self.steps, "mean_speed": json_number(self.mean_speed),
            "route_completion": json_number(self.route_completion), "completed": self.completed,
            "collisions": self.collisions, "intent": self.intent,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ClosedLoopStats:
        intervals = tuple(Interval(from_json_number(i["mean"]), from_json_number(i["low"]),
                                   from_json_number(i["high"]), int(i["n"]), float(i["confidence"]))
                          for i in data["distance_diff"])
        return cls(data["condition"], int(data["n_seeds"]), tuple(data["checkpoints"]), intervals,
                   float(data["shadow_brakes"]), float(data["brakes"]), float(data["steps"]),
                   from_json_number(data["mean_speed"]), from_json_number(data["route_completion"]),
                   int(data["completed"]), int(data["collisions"]), data.get("intent", "none"))


def closed_loop_stats(condition: str, episodes: Mapping[int, EpisodeSummary],
                      baselines: Mapping[int, EpisodeSummary], checkpoints: Sequence[float],
                      confidence: float = 0.95, intent: str = "none") -> ClosedLoopStats:
    """Compare a condition's episodes with the baselines of the same seeds (seeds missing on either side
    are left out)."""
    seeds = sorted(set(episodes) & set(baselines))
    eps = [episodes[s] for s in seeds]
    intervals = tuple(
        t_interval([episodes[s].distances[i] - baselines[s].distances[i] for s in seeds], confidence)
        for i in range(len(checkpoints))
    )

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else math.nan

    return ClosedLoopStats(
        condition=condition, n_seeds=len(seeds), checkpoints=tuple(float(c) for c in checkpoints),
        distance_diff=intervals, shadow_brakes=mean([e.shadow_brake_steps for e in eps]),
        brakes=mean([e.brake_steps for e in eps]), steps=mean([e.steps for e in eps]),
        mean_speed=mean([e.mean_speed for e in eps]), route_completion=mean([e.route_completion for e in eps]),
        completed=sum(e.completed for e in eps), collisions=sum(e.collided for e in eps), intent=intent,
    )


# -- seed planning ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SeedPlan:
    """How many seeds a seed-level t-test needs to detect ``effect_size`` (Cohen's d over per-seed means)
    with ``power`` at level ``alpha`` (``alpha_family`` / ``family_size``, the first step of Holm).

    ``seeds`` is None when the effect is zero (undetectable at any number of seeds).
    """

    condition: str
    effect_size: float
    effect_m: float
    seed_sd: float
    pilot_seeds: int
    power: float
    alpha: float
    family_size: int
    seeds: int | None
    achieved_power: float | None

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        for key in ("effect_size", "effect_m", "seed_sd", "achieved_power"):
            data[key] = json_number(data[key]) if data[key] is not None else None
        return data


def plan_seeds(condition: str, seed_means: Sequence[float], *, effect_m: float | None = None,
               power: float = 0.8, alpha: float = DEFAULT_ALPHA, family_size: int = 1,
               max_seeds: int = 100_000) -> SeedPlan:
    """Seeds needed for a condition, from a pilot's per-seed mean differences (statsmodels ``TTestPower``).

    ``effect_m`` is the effect to detect in metres (default: the pilot's own mean); the standardised
    effect is ``effect_m`` / sd(per-seed means). The test is two-sided at ``alpha / family_size``.
    """
    from statsmodels.stats.power import TTestPower

    x = np.asarray(seed_means, dtype=float)
    if x.size < 2:
        raise ValueError(f"condition {condition!r}: a pilot needs at least 2 seeds to estimate the spread "
                         f"of per-seed means, it has {x.size}")
    sd = float(np.std(x, ddof=1))
    effect = float(np.mean(x)) if effect_m is None else float(effect_m)
    size = abs(effect) / sd if sd > 0 else (math.inf if effect != 0 else 0.0)
    level = alpha / max(1, family_size)
    seeds: int | None
    achieved: float | None
    analysis = TTestPower()
    if size == 0.0:
        seeds, achieved = None, None
    elif math.isinf(size):
        seeds, achieved = 2, 1.0
    else:
        seeds = _smallest_n(analysis, size, level, power, max_seeds)
        achieved = t_test_power(size, seeds, level) if seeds else None
    return SeedPlan(condition, size, effect, sd, int(x.size), power, level, max(1, family_size), seeds,
                    achieved)


def t_test_power(effect_size: float, nobs: int, alpha: float) -> float:
    """Power of the two-sided one-sample t-test with ``nobs`` observations at standardised ``effect_size``.

    statsmodels' ``TTestPower`` first; where it returns NaN (its non-central t fails for large effects at
    few degrees of freedom) the same probability by numerical integration over the sample sd:
    P(|Z + λ| > t_c·S), λ = d·√n, Z ~ N(0, 1), S = √(V/df), V ~ χ²(df) — equal to statsmodels to ~1e-13
    wherever statsmodels is finite.
    """
    from statsmodels.stats.power import TTestPower

    with warnings.catch_warnings():  # a NaN is handled below; its warnings would only confuse
        warnings.simplefilter("ignore")
        value = float(TTestPower().power(effect_size=effect_size, nobs=nobs, alpha=alpha))
    if math.isfinite(value):
        return value
    from scipy import integrate, stats

    df = nobs - 1
    shift = abs(effect_size) * math.sqrt(nobs)
    critical = float(stats.t.isf(alpha / 2.0, df))

    def integrand(s: float) -> float:
        density = 2.0 * df * s * stats.chi2.pdf(df * s * s, df)  # of S = √(V/df)
        return (stats.norm.sf(critical * s - shift) + stats.norm.cdf(-critical * s - shift)) * density

    top = math.sqrt(float(stats.chi2.isf(1e-16, df)) / df)
    # split where the integrand changes fast: around λ/t_c (the rejection edge) and near 0
    marks = (shift / critical, (shift + 1) / critical, (shift + 8) / critical, 1 / critical, 8 / critical)
    edges = sorted({0.0, top, *(x for x in marks if x < top)})
    total = sum(integrate.quad(integrand, lo, hi, limit=200, epsabs=1e-14, epsrel=1e-12)[0]
                for lo, hi in zip(edges, edges[1:], strict=False))
    return min(1.0, max(0.0, total))


def _smallest_n(analysis: Any, size: float, alpha: float, power: float, max_seeds: int) -> int | None:
    """The smallest whole number of seeds (≥ 2) reaching ``power``: solve_power's real-valued n is only a hint
    (it can fail or land off by a few for very large effects), so walk down and up from it."""
    def enough(n: int) -> bool:
        return t_test_power(size, n, alpha) >= power

    try:
        with warnings.catch_warnings():  # non-convergence only means no hint: the walk below decides
            warnings.simplefilter("ignore")
            approx = float(analysis.solve_power(effect_size=size, nobs=None, alpha=alpha, power=power))
    except (ValueError, RuntimeError, ArithmeticError):
        approx = math.nan
    n = min(max_seeds, max(2, math.ceil(approx))) if math.isfinite(approx) else 2
    while n > 2 and enough(n - 1):
        n -= 1
    while not enough(n):
        if n >= max_seeds:
            return None
        n += 1
    return n
