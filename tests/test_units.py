"""Every recorded channel carries its true unit; the excitation's is the unit of the run's mode."""

from __future__ import annotations

import pytest

from hilident.io.recording import RunWriter, read_run
from hilident.units import EXCITATION_UNIT_OF_MODE, display_unit, recorded_units, units_in_mode
from support.fresh_recording import TRANSPORT_CONFIGS, record, twin_device

#: Units of the channels whose unit never depends on the mode.
FIXED_UNITS = {
    "sample_index": "1",
    "time_s": "s",
    "torque_nm": "N*m",
    "torque_cmd_nm": "N*m",
    "position_m": "m",
    "load_position_m": "m",
    "velocity_mps": "m/s",
}


def test_units_in_mode_replaces_only_the_excitation():
    names = ["sample_index", "excitation", "velocity_mps"]
    assert units_in_mode(names, ["1", "1", "m/s"], "velocity") == ["1", "m/s", "m/s"]
    assert units_in_mode(names, ["1", "1", "m/s"], "position") == ["1", "m", "m/s"]
    assert units_in_mode(names, ["1", "1", "m/s"], "torque_injection") == ["1", "N*m", "m/s"]
    assert units_in_mode(names, ["1", "1", "m/s"], "no such mode") == ["1", "1", "m/s"]


def test_an_older_recordings_dimensionless_excitation_reads_as_its_modes_unit(tmp_path):
    path = tmp_path / "old.h5"
    with RunWriter(
        path, ["sample_index", "excitation", "torque_nm"], ["1", "1", "N*m"], 1000.0, attrs={"mode": "velocity"}
    ) as w:
        w.append([[0.0, 0.1, 0.2], [1.0, 0.1, 0.3]])
    run = read_run(path)  # an older file is read as it is stored
    assert run.units["excitation"] == "1"
    units = recorded_units(run.units, run.attrs)
    assert units == {"sample_index": "1", "excitation": "m/s", "torque_nm": "N*m"}
    assert recorded_units(run.units, {}) == run.units  # no mode: nothing to go by
    assert recorded_units({"excitation": "N*m"}, {"mode": "velocity"}) == {"excitation": "N*m"}  # stored wins


def test_display_unit_writes_the_product_dot():
    assert display_unit("N*m") == "N·m" and display_unit("m/s") == "m/s"


@pytest.mark.parametrize("transport", sorted(TRANSPORT_CONFIGS))
def test_every_adapter_reports_the_excitation_in_the_unit_of_its_mode(transport):
    with twin_device(TRANSPORT_CONFIGS[transport]) as (cfg, device):
        ad = device.adapter
        for mode, unit in EXCITATION_UNIT_OF_MODE.items():
            names = ad.configure(cfg.run.sample_rate_hz, mode)
            units = dict(zip(names, ad.channel_units, strict=True))
            assert units["excitation"] == unit, mode
            assert {n: u for n, u in units.items() if n != "excitation"} == {
                n: FIXED_UNITS[n] for n in names if n != "excitation"
            }


@pytest.mark.parametrize("transport", sorted(TRANSPORT_CONFIGS))
def test_a_fresh_recording_stores_every_channels_true_unit(tmp_path, transport):
    modes = ("torque", "velocity", "position") if transport == "serial" else ("torque", "velocity")
    for mode, path in record(tmp_path, TRANSPORT_CONFIGS[transport], modes).items():
        run = read_run(path, require_complete=True)
        assert run.attrs["mode"] == mode
        assert run.units["excitation"] == EXCITATION_UNIT_OF_MODE[mode]
        for name, unit in run.units.items():
            if name != "excitation":
                assert unit == FIXED_UNITS[name], (mode, name)
        assert run.n_samples > 0
