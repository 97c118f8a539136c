"""The twins' one simulated clock and one table player, on their own (no thread, no wall clock)."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.clock import SimClock, TablePlayer, cut_at
from hilident.emulator.device import build_drive

LOOP_HZ = 1000.0


class Counter:
    """A firmware for :meth:`SimClock.step` that plays ``length`` samples and counts the coast."""

    def __init__(self, length: int, rate_hz: float = 100.0):
        self.length, self.sample_rate_hz = length, rate_hz
        self.produced = 0
        self.idled = 0

    @property
    def running(self) -> bool:
        return self.produced < self.length

    def advance(self, n_samples: int) -> None:
        self.produced += max(0, min(n_samples, self.length - self.produced))

    def idle(self, n_ticks: int) -> None:
        self.idled += n_ticks


@pytest.mark.parametrize("time_scale", [0.5, 1.0, 4.0])
def test_a_run_is_paced_at_the_time_scale(time_scale):
    clock = SimClock(LOOP_HZ, time_scale)
    clock.start_run(10.0)
    done = 0
    for k in range(1, 201):  # 2 s of wall time, 10 ms a step
        done += clock.samples_due(10.0 + 0.01 * k, done, 100.0)
    assert done == pytest.approx(2.0 * 100.0 * time_scale, abs=1)


def test_a_stall_never_bursts_and_the_run_resumes_from_now():
    clock = SimClock(LOOP_HZ, 1.0, max_catch_up_s=0.05)
    clock.start_run(0.0)
    assert clock.samples_due(0.01, 0, 1000.0) == 10
    assert clock.samples_due(1.01, 10, 1000.0) == 50  # a second asleep: 50 ms of samples, not 1000
    assert clock.samples_due(1.02, 60, 1000.0) <= 0  # the run resumed at 1.01: those 50 were ahead
    assert clock.samples_due(1.07, 60, 1000.0) == 10  # and on at the rate from there


def test_a_run_that_ends_coasts_for_its_coast_time_then_stops():
    clock = SimClock(LOOP_HZ, 2.0, coast_s=0.5)
    fw = Counter(length=10)
    clock.start_run(0.0)
    clock.step(fw, 0.1)  # due 20, the run has 10 left: it ends in this step
    assert fw.produced == 10 and not fw.running and clock.coasting
    for k in range(1, 101):
        clock.step(fw, 0.1 + 0.01 * k)
    assert fw.idled == int(0.5 * LOOP_HZ) and not clock.coasting  # 0.5 s simulated, at twice the wall rate
    clock.step(fw, 5.0)
    assert fw.idled == int(0.5 * LOOP_HZ)


def test_a_new_run_ends_the_coast():
    clock = SimClock(LOOP_HZ)
    clock.start_coast(0.0)
    clock.start_run(0.001)
    assert not clock.coasting and clock.coast_ticks(1.0) == 0


def test_playback_is_cut_where_an_injected_fault_is_due():
    assert cut_at(0, 100, [0.3], 100.0) == 30  # sample 30 starts at 0.3 s: the fault starts it
    assert cut_at(30, 100, [0.3], 100.0) == 100  # due at the first sample: nothing to cut
    assert cut_at(0, 10, [0.3, 0.05], 100.0) == 5  # the first one due
    assert cut_at(0, 10, [1.0], 100.0) == 10


def _drive():
    cfg = parse_config(
        "[limits]\ntorque_nm = 5.0\nvelocity_mps = 1.0\nposition_min_m = -0.5\nposition_max_m = 0.5\n"
        '[emulator]\npreset = "clean"\n'
    )
    return build_drive(cfg.emulator, find_driver("myrio-board"))


def test_the_player_holds_each_sample_for_the_divider_and_rows_start_each_period():
    drive, twin = _drive(), _drive()
    for d in (drive, twin):
        d.set_limits(5.0, 1.0, -0.5, 0.5)
        d.enable()
    player = TablePlayer(drive, 4, drive.tuning.loop_rate_hz)
    values = np.array([0.1, -0.2, 0.3])
    played = player.play(values, 0)
    ticks = twin.run(np.repeat(values, 4))
    assert played.kept == 3 and not played.faulted and played.end == 3
    np.testing.assert_array_equal(played.rows, ticks[::4])
    assert player.sample_rate_hz == drive.tuning.loop_rate_hz / 4


def test_the_player_records_the_averaged_channels_as_the_mean_of_their_period():
    """The myrio-board averages its torques over each sample period (PROTOCOL.md section 7); everything else is the
    period's first tick."""
    board = find_driver("myrio-board")
    assert board.averaged_channels == ("torque_cmd_nm", "torque_nm")
    drive, twin = _drive(), _drive()
    for d in (drive, twin):
        d.set_limits(5.0, 1.0, -0.5, 0.5)
        d.enable()
    player = TablePlayer(drive, 4, drive.tuning.loop_rate_hz, board.averaged_channels)
    values = np.array([0.1, -0.2, 0.3, 0.0])
    played = player.play(values, 0)
    ticks = twin.run(np.repeat(values, 4))
    mean = drive.columns_of(board.averaged_channels, "averaged")
    first = [i for i in range(ticks.shape[1]) if i not in mean]
    np.testing.assert_array_equal(played.rows[:, first], ticks[::4, first])
    np.testing.assert_allclose(played.rows[:, mean], ticks[:, mean].reshape(4, 4, len(mean)).mean(axis=1))
    # the loop changes the torque within a period: the mean is not the first tick's value
    assert np.abs(played.rows[:, mean] - ticks[::4, mean]).max() > 1e-3


def test_the_player_keeps_the_samples_up_to_the_one_in_which_the_drive_faulted():
    drive = _drive()
    drive.set_limits(0.05, 1.0, -0.5, 0.5)  # a torque limit the first big sample trips
    drive.enable()
    player = TablePlayer(drive, 2, drive.tuning.loop_rate_hz)
    assert not player.play(np.zeros(10), 0).faulted
    played = player.play(np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]), 10)
    assert played.faulted and played.fault_sample == 13 and played.kept == 4 and played.end == 14
    assert not drive.enabled


def test_the_clock_and_the_player_are_fast():
    import time

    t0 = time.process_time()
    clock = SimClock(LOOP_HZ)
    fw = Counter(length=10**9, rate_hz=1000.0)
    for k in range(20000):
        clock.step(fw, 0.001 * k)
    assert time.process_time() - t0 < 1.0
