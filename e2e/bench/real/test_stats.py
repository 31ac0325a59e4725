"""The comparison's statistics: exact Mann-Whitney p with ties, the bootstrap CI (pure)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from e2e.bench.real.stats import bootstrap_reduction_ci, mann_whitney_less, reduction


def test_six_runs_all_below_six_controls_give_one_split_in_924() -> None:
    treated = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]
    control = [0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    assert mann_whitney_less(treated, control) == pytest.approx(1 / 924)
    assert mann_whitney_less(control, treated) == 1.0


def test_tied_zeros_count_by_their_mid_ranks() -> None:
    # pooled 0 0 0 1 2 -> mid-ranks 2 2 2 4 5; treated {0, 0} has R = 4, and of the 10 splits
    # only the 3 pairs of zeros reach R <= 4
    assert mann_whitney_less([0.0, 0.0], [0.0, 1.0, 2.0]) == pytest.approx(3 / 10)
    # {0, 0, 0} of 0 0 0 0 0 1: half the 20 splits hold the 1
    assert mann_whitney_less([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]) == pytest.approx(0.5)


def test_identical_samples_give_a_p_near_one_half() -> None:
    sample = [0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    assert 0.45 < mann_whitney_less(sample, sample) < 0.65


def test_all_values_tied_tell_nothing() -> None:
    assert mann_whitney_less([0.0] * 6, [0.0] * 6) == 1.0


def test_without_ties_the_exact_p_is_scipys() -> None:
    rng = np.random.default_rng(3)
    for shift in (-0.5, 0.3, 1.2):
        treated, control = rng.normal(size=6), rng.normal(size=7) + shift
        expected = mannwhitneyu(treated, control, alternative="less", method="exact").pvalue
        assert mann_whitney_less(list(treated), list(control)) == pytest.approx(expected)


def test_large_samples_fall_back_to_the_tie_corrected_normal_approximation() -> None:
    rng = np.random.default_rng(5)
    treated = rng.integers(0, 5, size=15).astype(float)  # C(30, 15) splits: too many
    control = rng.integers(1, 6, size=15).astype(float)
    expected = mannwhitneyu(treated, control, alternative="less", method="asymptotic").pvalue
    assert mann_whitney_less(list(treated), list(control)) == pytest.approx(expected)


def test_reduction_is_the_share_of_the_controls_misses_avoided() -> None:
    assert reduction(0.001, 0.02) == pytest.approx(0.95)
    assert math.isnan(reduction(0.001, 0.0))


def test_the_bootstrap_ci_contains_the_point_reduction_and_is_seeded() -> None:
    treated = [0.001, 0.002, 0.0, 0.003, 0.001, 0.004]
    control = [0.02, 0.03, 0.01, 0.05, 0.02, 0.04]
    point = reduction(float(np.median(treated)), float(np.median(control)))
    lo, hi = bootstrap_reduction_ci(treated, control)
    assert lo <= point <= hi < 1.0
    assert bootstrap_reduction_ci(treated, control) == (lo, hi)
    narrow = bootstrap_reduction_ci(treated, control, level=0.5)
    assert lo <= narrow[0] <= narrow[1] <= hi


def test_resamples_with_a_zero_control_median_are_skipped() -> None:
    lo, hi = bootstrap_reduction_ci([0.0, 0.01], [0.0, 0.0])
    assert math.isnan(lo) and math.isnan(hi)
    # control [0, 0, 0.1]: only the resamples with two or three 0.1 draws count
    lo, hi = bootstrap_reduction_ci([0.05, 0.05], [0.0, 0.0, 0.1], resamples=2000)
    assert lo == pytest.approx(0.5) and hi == pytest.approx(0.5)


def test_an_empty_or_non_finite_sample_is_refused() -> None:
    with pytest.raises(ValueError, match="treated"):
        mann_whitney_less([], [0.1])
    with pytest.raises(ValueError, match="control"):
        bootstrap_reduction_ci([0.1], [math.nan])
