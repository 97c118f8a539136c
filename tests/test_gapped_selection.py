"""Whole periods that miss a few samples, laid end to end with the missing ones marked."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.errors import DataError
from hilident.pipeline.selection import select_gapped_periods

P = 100


def test_periods_missing_a_few_samples_are_laid_end_to_end_with_the_missing_ones_marked():
    index = np.delete(np.arange(5 * P), [150, 151, 233, 420])  # periods 1, 2 and 4 miss some; 3 none
    values = index * 10.0
    sel = select_gapped_periods(index, P)
    assert sel.periods == [1, 2, 3, 4]
    assert sel.present.size == 4 * P and (~sel.present).sum() == 4
    spread = sel.spread(values)
    expected = np.arange(P, 5 * P) * 10.0
    missing = ~sel.present
    np.testing.assert_array_equal(spread[~missing], expected[~missing])
    assert np.isnan(spread[missing]).all()
    assert np.flatnonzero(missing).tolist() == [50, 51, 133, 320]


def test_a_period_missing_too_many_samples_is_left_out_and_said():
    index = np.delete(np.arange(4 * P), np.arange(210, 240))  # period 2 misses three tenths
    sel = select_gapped_periods(index, P)
    assert sel.periods == [1, 3]
    assert any("1 of 3 excitation periods missed too many" in w for w in sel.warnings)


def test_fewer_than_two_usable_periods_is_a_data_error():
    with pytest.raises(DataError, match="only 1 excitation period"):
        select_gapped_periods(np.delete(np.arange(3 * P), np.arange(210, 250)), P, "trial")
