"""Which recorded rows of the friction test each constant-velocity window averages over."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilident.events import StreamStats
from hilident.session.experiment import Experiment
from hilident.session.run import Session


def recorded(index) -> Experiment:
    index = np.asarray(index, dtype=np.int64)
    return Experiment("friction", Path("friction.h5"), {"sample_index": index}, StreamStats())


def test_a_window_with_a_few_cycles_missing_is_averaged_over_the_samples_it_has():
    index = np.delete(np.arange(1000), [150, 151, 420])  # two skipped cycles in the first window, one in the second
    exp = recorded(index)
    kept = Session._window_rows(exp, [(100, 300, 0.1), (400, 600, -0.1)])
    assert kept == [(100, 298, 0.1), (398, 597, -0.1)]
    for (a, b, _), (lo, hi) in zip(kept, [(100, 300), (400, 600)], strict=True):
        rows = exp.samples["sample_index"][a:b]
        assert rows.min() >= lo and rows.max() < hi  # only the window's own samples, none of its neighbours'


def test_a_window_missing_more_than_a_tenth_of_its_samples_is_left_out():
    index = np.delete(np.arange(1000), np.arange(120, 150))  # 30 of the window's 200 samples lost
    assert Session._window_rows(recorded(index), [(100, 300, 0.1), (400, 600, 0.2)]) == [(370, 570, 0.2)]


def test_a_window_nobody_recorded_is_left_out():
    assert Session._window_rows(recorded(np.arange(500)), [(600, 800, 0.1)]) == []
