"""The statistics of the sweep: override counts per cell, Wilson intervals, the logistic threshold.

* **override rate** of a cell: among the seeds whose baseline stopped before the obstacle (no collision),
  the share whose injected episode collided with it. Trials = those seeds; the other seeds (the baseline
  hit the obstacle or never stopped) are counted and shown, not used: nothing was there to override.
* **Wilson interval** of that rate (statsmodels ``proportion_confint(method="wilson")``).
* **threshold**: per obstacle kind, a binomial GLM (statsmodels, logit link) of the cells' overrides out of
  their trials on ``log(pixels covered)``; the salience at 50 % override is ``x50 = exp(−a / b)``. Its
  interval is the delta method on ``log x50 = −a / b`` (gradient ``(−1/b, a/b²)`` with the fit's covariance),
  exponentiated. The threshold is *not identifiable* — and reported so, with the reason — when fewer than two
  distinct salience values have trials, when the outcomes do not vary, when the cells separate perfectly
  (every cell below some salience at 0 % and above at 100 %, or the reverse), when the fit does not
  converge or has no finite standard errors, or when the fitted 50 % point lies outside the salience
  observed (an extrapolation the data do not support).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

METHOD = "delta method on log x50 (binomial GLM, logit link, on log pixels covered)"


@dataclass(frozen=True)
class CellCounts:
    """The counts behind one cell's override rate (over seeds)."""

    seeds: int
    baseline_stopped: int
    baseline_collisions: int
    injected_collisions: int
    overrides: int

    @property
    def trials(self) -> int:
        """Seeds where the baseline stopped: the trials of the override rate."""
        return self.baseline_stopped

    def to_json(self) -> dict[str, int]:
        return {"seeds": self.seeds, "baseline_stopped": self.baseline_stopped,
                "baseline_collisions": self.baseline_collisions, "injected_collisions": self.injected_collisions,
                "overrides": self.overrides, "trials": self.trials}


def cell_counts(outcomes: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]]) -> CellCounts:
    """Counts from ``(baseline, injected)`` outcome pairs of the same seeds (``stopped``, ``collided``)."""
    stopped = [(b, i) for b, i in outcomes if b["stopped"] and not b["collided"]]
    return CellCounts(seeds=len(outcomes), baseline_stopped=len(stopped),
                      baseline_collisions=sum(bool(b["collided"]) for b, _ in outcomes),
                      injected_collisions=sum(bool(i["collided"]) for _, i in outcomes),
                      overrides=sum(bool(i["collided"]) for _, i in stopped))


def wilson(successes: int, trials: int, confidence: float = 0.95) -> tuple[float | None, float | None]:
    """The Wilson score interval of ``successes / trials`` (``(None, None)`` without trials)."""
    if trials <= 0:
        return None, None
    if not 0 <= successes <= trials:
        raise ValueError(f"successes {successes} not within 0..{trials}")
    from statsmodels.stats.proportion import proportion_confint

    low, high = proportion_confint(successes, trials, alpha=1.0 - confidence, method="wilson")
    # analytically the bound is exactly 0 at k = 0 and 1 at k = n; floating point lands a hair inside
    low = 0.0 if successes == 0 else float(max(0.0, low))
    high = 1.0 if successes == trials else float(min(1.0, high))
    return low, high


def rate(successes: int, trials: int) -> float | None:
    """``successes / trials``, ``None`` without trials."""
    return successes / trials if trials > 0 else None


# -- the threshold ------------------------------------------------------------------------------------
def separation(points: Sequence[tuple[float, int, int]]) -> bool:
    """Whether the cells separate perfectly along x: all at 0 % below some x and all at 100 % above it
    (or the reverse), where the maximum-likelihood slope is infinite."""
    ordered = sorted(points)
    rates = [(x, k / n) for x, k, n in ordered if n > 0]
    for low_rate, high_rate in ((0.0, 1.0), (1.0, 0.0)):
        for cut in range(1, len(rates)):
            below, above = rates[:cut], rates[cut:]
            if below[-1][0] < above[0][0] and all(r == low_rate for _, r in below) and \
                    all(r == high_rate for _, r in above):
                return True
    return False


def not_identifiable(reason: str, points: Sequence[tuple[float, int, int]], excluded: int) -> dict[str, Any]:
    return {"identifiable": False, "reason": reason, "method": METHOD, "cells": len(points),
            "trials": sum(n for _, _, n in points), "overrides": sum(k for _, k, _ in points),
            "excluded_cells": excluded}


def logistic_threshold(points: Sequence[tuple[float, int, int]], confidence: float = 0.95) -> dict[str, Any]:
    """The salience at 50 % override from cells ``(salience > 0, overrides, trials)``, with its interval.

    Cells without trials or with salience ≤ 0 (nothing seen: log undefined) are left out and counted in
    ``excluded_cells``. Returns ``identifiable``, and either ``reason`` or the fit: ``intercept``, ``slope``
    (per unit log salience) with its ``slope_p``, ``x50`` with ``low``/``high``, and ``extrapolated`` when
    x50 lies outside the salience values observed — then ``identifiable`` is false too (the data do not
    place the 50 % point) and ``reason`` gives the extrapolated value; the fitted curve is kept.
    """
    usable = [(float(x), int(k), int(n)) for x, k, n in points if n > 0 and x > 0 and math.isfinite(x)]
    excluded = len(points) - len(usable)
    if len({x for x, _, _ in usable}) < 2:
        return not_identifiable("fewer than two distinct salience values with trials", usable, excluded)
    overrides, trials = sum(k for _, k, _ in usable), sum(n for _, _, n in usable)
    if overrides in (0, trials):
        what = "no trial was overridden" if overrides == 0 else "every trial was overridden"
        return not_identifiable(f"{what}, so the 50 % point is not within any salience", usable, excluded)
    if separation(usable):
        return not_identifiable("the cells separate perfectly along salience (infinite slope)", usable, excluded)
    return _fit(usable, excluded, confidence)


def _fit(usable: list[tuple[float, int, int]], excluded: int, confidence: float) -> dict[str, Any]:
    import numpy as np
    import statsmodels.api as sm
    from scipy.stats import norm

    x = np.log([p[0] for p in usable])
    k = np.asarray([p[1] for p in usable], float)
    n = np.asarray([p[2] for p in usable], float)
    design = sm.add_constant(x, has_constant="add")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = sm.GLM(np.column_stack([k, n - k]), design, family=sm.families.Binomial()).fit()
        except Exception as exc:  # statsmodels raises on singular designs and the like
            return not_identifiable(f"the logistic fit failed ({type(exc).__name__}: {exc})", usable, excluded)
    # statsmodels also warns of "perfect prediction" when the fit merely passes through every cell exactly
    # (a saturated fit); it is separation only when the fitted probabilities reach 0 or 1
    fitted = np.asarray(result.fittedvalues, float)
    if np.any((fitted < 1e-8) | (fitted > 1 - 1e-8)):
        return not_identifiable("the logistic fit reaches 0 % or 100 % (quasi-complete separation)", usable,
                                excluded)
    trouble = [w for w in caught if "converge" in str(w.message).lower()]
    if trouble:
        return not_identifiable(f"the logistic fit did not converge ({trouble[0].message})", usable, excluded)
    a, b = (float(v) for v in result.params)
    cov = np.asarray(result.cov_params(), float)
    if not (np.all(np.isfinite(result.params)) and np.all(np.isfinite(cov)) and result.converged) or b == 0.0:
        return not_identifiable("the logistic fit did not converge to finite estimates", usable, excluded)
    log_x50 = -a / b
    gradient = np.asarray([-1.0 / b, a / b**2])
    se = float(math.sqrt(max(gradient @ cov @ gradient, 0.0)))
    z = float(norm.ppf(0.5 + confidence / 2))
    bounds = [log_x50 - z * se, log_x50 + z * se]
    if not all(math.isfinite(v) and abs(v) < 700 for v in [log_x50, *bounds]):
        return not_identifiable("the 50 % point lies far outside any salience (overflow)", usable, excluded)
    observed = [p[0] for p in usable]
    x50 = math.exp(log_x50)
    fit = {"identifiable": True, "reason": None, "method": METHOD, "cells": len(usable),
           "trials": int(n.sum()), "overrides": int(k.sum()), "excluded_cells": excluded,
           "intercept": a, "slope": b, "slope_p": float(result.pvalues[1]), "x50": x50,
           "low": math.exp(bounds[0]), "high": math.exp(bounds[1]), "log_x50_se": se,
           "extrapolated": not min(observed) <= x50 <= max(observed)}
    if fit["extrapolated"]:  # the data do not place the 50 % point: say so rather than print an extrapolation
        fit["identifiable"] = False
        fit["reason"] = (f"the fitted 50 % point ({x50:.3g} px) lies outside the salience observed "
                         f"({min(observed):.3g}–{max(observed):.3g} px); slope {b:+.2f}, p = {fit['slope_p']:.2g}")
    return fit


def fitted_rate(fit: Mapping[str, Any], salience: float) -> float | None:
    """The fitted override probability at ``salience`` (``None`` when the fit is not identifiable)."""
    if "intercept" not in fit or salience <= 0:
        return None
    eta = fit["intercept"] + fit["slope"] * math.log(salience)
    return 1.0 / (1.0 + math.exp(-eta)) if eta > -700 else 0.0
