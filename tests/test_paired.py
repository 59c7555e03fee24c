"""Paired comparisons (mhrc.eval.paired) checked against hand computations on a small table."""

from __future__ import annotations

import itertools
from math import comb

import numpy as np
import pytest

from mhrc.eval.paired import Outcome, compare, mcnemar_exact, paired_bootstrap_ci

# arm a, arm b: episode -> (success, TS, AS). e5 only in a, e6 only in b.
A = {
    "e1": Outcome(True, 10, 8),
    "e2": Outcome(True, 12, 9),
    "e3": Outcome(False, 30, 20),
    "e4": Outcome(True, 11, 7),
    "e5": Outcome(True, 9, 9),
}
B = {
    "e1": Outcome(True, 12, 8),
    "e2": Outcome(False, 30, 25),
    "e3": Outcome(False, 30, 22),
    "e4": Outcome(False, 30, 21),
    "e6": Outcome(True, 13, 10),
}


def test_paired_figures_match_a_hand_computation() -> None:
    got = compare("a", "b", A, B, resamples=4000)
    assert got.episodes == ("e1", "e2", "e3", "e4") and got.only_a == ("e5",) and got.only_b == ("e6",)
    # TS differences a - b: -2, -18, 0, -19 -> mean -39/4; AS: 0, -16, -2, -14 -> -8
    assert got.ts_diff == pytest.approx(-9.75) and got.as_diff == pytest.approx(-8.0)
    # discordant: a alone solved e2 and e4, b alone solved none: p = 2 * (1/2)^2 = 0.5
    assert (got.a_only_solved, got.b_only_solved) == (2, 0) and got.mcnemar_p == pytest.approx(0.5)
    assert got.ts_ci is not None and got.ts_ci[0] <= -9.75 <= got.ts_ci[1]


def test_the_exact_mcnemar_p_is_the_binomial_tail_doubled() -> None:
    # 1 against 6 discordant pairs: 2 * (C(7,0) + C(7,1)) / 2^7 = 16/128
    assert mcnemar_exact(1, 6) == pytest.approx(0.125)
    assert mcnemar_exact(6, 1) == pytest.approx(0.125)
    assert mcnemar_exact(3, 3) == pytest.approx(1.0) and mcnemar_exact(0, 0) == 1.0
    n, k = 12, 2
    assert mcnemar_exact(k, n - k) == pytest.approx(2 * sum(comb(n, i) for i in range(k + 1)) / 2**n)
    with pytest.raises(ValueError):
        mcnemar_exact(-1, 2)


def test_the_paired_interval_approaches_the_exact_bootstrap_distribution() -> None:
    # every one of the 4^4 equally likely resamples of four differences, enumerated: the exact
    # bootstrap distribution of the mean, whose 2.5th and 97.5th percentiles the drawn interval nears
    diffs = [-2.0, -18.0, 0.0, -19.0]
    means = sorted(float(np.mean(pick)) for pick in itertools.product(diffs, repeat=4))
    lo, hi = paired_bootstrap_ci(diffs, resamples=40_000)
    assert lo == pytest.approx(np.percentile(means, 2.5), abs=0.6)
    assert hi == pytest.approx(np.percentile(means, 97.5), abs=0.6)
    # the same differences give the same interval; equal differences an interval of one point
    assert paired_bootstrap_ci(diffs, resamples=500) == paired_bootstrap_ci(diffs, resamples=500)
    assert paired_bootstrap_ci([3.0, 3.0, 3.0]) == (3.0, 3.0)


def test_arms_that_share_no_episode_give_no_figures() -> None:
    got = compare("a", "b", {"e5": A["e5"]}, {"e6": B["e6"]})
    assert got.n == 0 and got.ts_diff is None and got.mcnemar_p is None and got.only_a == ("e5",)
    with pytest.raises(ValueError):
        paired_bootstrap_ci([])
