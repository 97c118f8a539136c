"""``drivers check`` tries a folder's filter slot on a throw-away twin, as ``hilident run`` uploads a notch.

The documented families' tables (:mod:`support.filter_families`) pass: slot 0
is read, written bypassed, read back, enabled, read back and put back as it
was. A table whose objects are all in the EDS but whose values the drive
cannot take is refused, naming the ``[filters]`` key and the object: a scale
that puts the notch's frequency outside the object's EDS limits, an enable
value its object refuses, a word block whose enabled state word reads bypassed.
``drivers check --no-twin`` passes those same tables: the twin is what refuses.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hilident.cli.driver_trial import FilterTrial, try_filter_slots
from hilident.cli.main import main
from hilident.config.tables import parse_config
from hilident.drivers.description import load_driver
from hilident.drivers.filter_trial import trial_filter_slot, trial_notch
from hilident.filters.notch import chain_response
from hilident.progress import Progress
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.session.connection import connect_device
from support.filter_families import FAMILIES, family_folder

pytestmark = pytest.mark.twin

_LIMITS = "[limits]\ntorque_nm = 1.0\nvelocity_mps = 1.0\nposition_min_m = -1.0\nposition_max_m = 1.0\n"


_folder = family_folder


class _Recorder:
    """An adapter whose filter-slot calls are recorded, in order."""

    def __init__(self, adapter):
        self.adapter, self.calls = adapter, []
        self.port, self.identity = adapter.port, adapter.identity

    def __getattr__(self, name):
        method = getattr(self.adapter, name)

        def call(*args, **kwargs):
            self.calls.append((name, kwargs.get("enabled")) if name == "write_filter" else name)
            return method(*args, **kwargs)

        return call


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_a_documented_table_passes_the_trial_and_the_slot_is_put_back(tmp_path, name):
    folder = _folder(tmp_path, FAMILIES[name])
    driver = load_driver(folder)
    cfg = parse_config(_LIMITS, "<test>")
    cfg = dataclasses.replace(cfg, device=dataclasses.replace(cfg.device, port="emulator"))
    device = connect_device(cfg, driver, Progress(enabled=False))
    try:
        before = device.adapter.save_filter(0)
        twin_before = device.emulator.drive.filters.read(0)
        spy = _Recorder(device.adapter)
        errors = trial_filter_slot(spy, driver.sections["filters"], str(folder / "driver.toml"))
        after = device.adapter.save_filter(0)
        twin_after = device.emulator.drive.filters.read(0)
    finally:
        device.close()
    assert errors == []
    writes = [c for c in spy.calls if isinstance(c, tuple)]
    assert writes == [("write_filter", False), ("write_filter", True)]  # bypassed first, then enabled
    assert spy.calls[-2:] == ["restore_filter", "save_filter"]  # put back, and read to see it is
    assert after == before  # the slot's objects hold what they held
    # and the twin's torque command runs through what it ran through (a slot without an enable runs its restored
    # fields, zeros on poles: the identity all the same)
    freqs, rate = np.linspace(1.0, 0.45 * driver.loop_rate_hz, 50), driver.loop_rate_hz
    ran = [chain_response([b] if on else [], freqs, rate) for b, on in (twin_before, twin_after)]
    assert np.allclose(ran[0], ran[1], atol=1e-6)


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_drivers_check_says_it_tried_the_slot(tmp_path, capsys, name):
    folder = _folder(tmp_path, FAMILIES[name])
    assert main(["drivers", "check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "filter slot 0: read, written bypassed, read back, enabled, read back and restored on a twin" in out


def _synapticon_with_a_limited_enable():
    """Synapticon's record with its enable as an UNSIGNED8 the drive limits to 0..1 (EDS HighLimit)."""
    drive = FAMILIES["synapticon-somanet"]
    objects = [
        (0x2023, 1, "Enabled", 0x5, "rw", False, 0, 0, 1) if o[:2] == (0x2023, 1) else o for o in drive.vendor_objects
    ]
    assert objects != drive.vendor_objects
    return dataclasses.replace(drive, vendor_objects=objects)


@pytest.mark.parametrize(
    ("drive", "old", "new", "words"),
    [
        # 1e-4 Hz a step: the notch's centre is beyond 0x3406:1's HighLimit of 5 000 000
        (
            FAMILIES["kollmorgen-akd"],
            "scales = { pole_hz = 0.001,",
            "scales = { pole_hz = 0.0001,",
            ("[filters.fields.pole_hz]", "0x3406:1", "too high"),
        ),
        # 1 kHz a step: the centre is one step, below 0x2023:2's LowLimit of 10
        (
            FAMILIES["synapticon-somanet"],
            "ranges = { center",
            "scales = { center = 1000 }\nranges = { center",
            ("[filters.fields.center]", "0x2023:2", "too low"),
        ),
        # on = 2 fits an UNSIGNED8, but this drive takes 0 or 1 only
        (
            _synapticon_with_a_limited_enable(),
            "enable_subindex = 1",
            "enable_subindex = 1\nenable_values = { on = 2, off = 0 }",
            ("[filters.enable_values]", "0x2023:1", "too high"),
        ),
        # type 7 (disabled) with Copley's designed bits: the enabled block reads bypassed
        (
            FAMILIES["copley-plus"],
            'objects = ["0x2106"]',
            'objects = ["0x2106"]\nenabled_value = 0xE110',
            ("[filters.enabled_value]", "0x2106", "bypassed"),
        ),
    ],
    ids=["kollmorgen-scale", "synapticon-scale", "synapticon-enable", "copley-state"],
)
def test_a_table_the_drive_cannot_take_is_refused_naming_key_and_object(tmp_path, capsys, drive, old, new, words):
    folder = _folder(tmp_path, drive, old, new)
    assert main(["drivers", "check", "--no-twin", str(folder)]) == 0  # the EDS alone cannot tell
    capsys.readouterr()
    trial = try_filter_slots(folder)
    assert trial.tried and len(trial.errors) == 1, trial.errors
    assert all(w in trial.errors[0] for w in words), trial.errors
    assert main(["drivers", "check", str(folder)]) == 2
    out = capsys.readouterr().out
    assert trial.errors[0] in out and "Traceback" not in out


def test_the_trial_notch_lies_inside_the_encoding_ranges():
    table = {"encoding": "center_band", "ranges": {"center": [10, 2000], "band": [1, 4000]}}
    encoding = FilterEncoding.from_table(table)
    assert trial_notch(encoding, 4000.0).center_hz == pytest.approx(1000.0)  # a quarter of the rate
    assert trial_notch(encoding, 16000.0).center_hz == pytest.approx(2000.0)  # clipped to the range
    assert trial_notch(encoding, 20.0).center_hz == pytest.approx(9.0)  # and below Nyquist above all
    # Beckhoff's BQFC, a field named center_hz, 20-1000 Hz
    bi_quad = FilterEncoding.from_table({"encoding": "center_ratio_damping", "ranges": {"center_hz": [20, 1000]}})
    assert trial_notch(bi_quad, 16000.0).center_hz == pytest.approx(1000.0)


def test_a_folder_without_filter_objects_or_slots_is_not_tried(tmp_path):
    plain = dataclasses.replace(FAMILIES["synapticon-somanet"], filter_table="")
    assert try_filter_slots(_folder(tmp_path / "plain", plain)) == FilterTrial()
    unused = try_filter_slots(_folder(tmp_path, FAMILIES["synapticon-somanet"], "filter_slots = 1", "filter_slots = 0"))
    assert not unused.tried and not unused.errors
    assert any("[board.filter_slots] is 0" in w for w in unused.warnings), unused.warnings
