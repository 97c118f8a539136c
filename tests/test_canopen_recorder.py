"""Recorder runs: a vendor-style drive's own generator plays, its own recorder records, the host reads the buffers.

The drives are written by :mod:`vendor_drives` (``recorder = "prbs"``: an
interleaved buffer and a PRBS generator with an output object; ``"sweep"``:
one buffer per channel, a logarithmic sine sweep and a sine, no output object).
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.cli.main import main
from hilident.config.tables import load_config
from hilident.drivers.description import load_driver, load_object_dictionary
from hilident.drivers.tools import check_driver_folder
from hilident.emulator.canopen.server import start
from hilident.emulator.factory import true_modes
from hilident.errors import ConfigError, DeviceError
from hilident.io.recording import read_run
from hilident.protocol.canopen_recorder import (
    MAX_LEN_SEQ_TAPS,
    GeneratorKind,
    generator_output,
    parse_recorder,
    prbs_bits,
)
from hilident.protocol.canopen_types import ObjectAddress
from hilident.session.excitation import build_excitation, excitation_recipe
from hilident.signals import generators as sig
from support.vendor_drives import VendorDrive, write_vendor_drive

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-canopen-gantry.toml"
FS = 1000.0
PRBS = VendorDrive("acme-recorder", recorder="prbs")
SWEEP = VendorDrive("acme-sweep", recorder="sweep")


def test_the_prbs_register_is_scipys_max_len_seq():
    for n in (4, 7, 10, 12):
        bits, _ = scipy.signal.max_len_seq(n)
        assert np.array_equal(prbs_bits(n, MAX_LEN_SEQ_TAPS[n], 2**n - 1), bits)
    # another seed is another phase of the same sequence
    shifted = prbs_bits(7, MAX_LEN_SEQ_TAPS[7], 127, seed=0x35)
    assert not np.array_equal(shifted, prbs_bits(7, MAX_LEN_SEQ_TAPS[7], 127)) and shifted.sum() == 64


@pytest.mark.parametrize("method", ["linear", "logarithmic"])
def test_the_generators_sweep_is_the_hosts_chirp(method):
    kind = GeneratorKind("chirp", 2, {}, method)
    values = {"amplitude": 2.0, "f_start_hz": 1.0, "f_end_hz": 80.0, "duration_s": 2.0}
    y = generator_output(kind, values, np.arange(2000) * 4, 4000.0)  # every 4th loop cycle: 1 kHz
    assert np.allclose(y, sig.chirp(2.0, 1.0, 80.0, 2.0, 1000.0, method=method), atol=1e-9)
    assert np.all(generator_output(kind, values, np.arange(8000, 8100), 4000.0) == 0.0)  # after its duration


def _session_config(tmp_path: Path, drive: VendorDrive, excitation: str) -> Path:
    folder = write_vendor_drive(tmp_path / "drivers", drive)
    text = CONFIG.read_text()
    text = text.replace('driver = "canopen-servo"', f'driver = "{folder.as_posix()}"')
    text = text.replace('acquisition = "auto"', 'acquisition = "recorder"').replace(
        "time_scale = 6.0", "time_scale = 20.0"
    )
    text = re.sub(r"\[excitation\][^\[]*", excitation, text)
    text = text.replace("[friction_test]", "[friction_test]\nenabled = false")
    # the torque follows the PRBS tick for tick
    text = text.replace("[emulator]\n", '[emulator]\npreset = "clean"\n', 1)
    path = tmp_path / "recorder.toml"
    path.write_text(text)
    return path


def test_a_whole_session_plays_the_drives_prbs_and_finds_the_resonance(tmp_path):
    path = _session_config(
        tmp_path,
        PRBS,
        '[excitation]\nkind = "prbs"\nmode = "torque"\namplitude_nm = 8.0\n'
        "register_length = 10\nduration_s = 3.1\nf_max_hz = 200.0\n\n",
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q", "--no-plots"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    cfg = load_config(path)
    ((true_f, _),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.005
    run = read_run(tmp_path / "out" / "identification.h5")
    x = build_excitation(cfg).samples
    assert run.complete and run.n_samples == len(x) == 4 * 1023
    assert summary["stream"]["lost_samples"] == 0 and summary["stream"]["samples"] == run.n_samples
    assert np.array_equal(run.samples["sample_index"], np.arange(run.n_samples))
    # the excitation column is what the drive's generator output object said: the host's PRBS, sample for sample
    assert np.array_equal(run.samples["excitation"], x)
    kinds = [e["kind"] for e in run.events]
    assert "capture_end" in kinds and "excitation_differs" not in kinds and "excitation_computed" not in kinds
    # the torque followed the generator (CST): the measured torque correlates with it
    assert np.corrcoef(run.samples["torque_nm"], x)[0, 1] > 0.99


@pytest.fixture
def twin(tmp_path):
    opened = []

    def make(drive: VendorDrive, **faults):
        folder = write_vendor_drive(tmp_path, drive)
        driver = load_driver(folder)
        cfg = load_config(CONFIG)
        cfg = replace(cfg, excitation=replace(cfg.excitation, amplitude_nm=8.0))
        emu_cfg = replace(cfg.emulator, preset="clean", time_scale=20.0, faults=replace(cfg.emulator.faults, **faults))
        emu = start(emu_cfg, driver, replace(cfg.device, driver=str(folder)))
        ad = CanopenDriveAdapter.open_device(replace(emu.device, acquisition="recorder", timeout_s=0.5), driver)
        opened.append((ad, emu))
        lim = cfg.limits
        ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        return ad, emu, cfg

    yield make
    for ad, emu in opened:
        ad.close()
        emu.close()


def _play(ad, cfg, **excitation):
    """Configure, set the recipe, stream the host's samples of it; returns (result, rows, host samples)."""
    ad.configure(FS, "torque")
    full = replace(cfg, excitation=replace(cfg.excitation, **excitation))
    x = build_excitation(full).samples
    ad.set_excitation_recipe(excitation_recipe(full))
    seen = []
    result = ad.stream(x, lambda i, rows: seen.append((i, rows)))
    return result, seen, x


def test_a_sine_sweep_is_recorded_channel_by_channel_and_its_excitation_computed(twin):
    ad, emu, cfg = twin(SWEEP)
    result, seen, x = _play(
        ad, cfg, kind="chirp", chirp_method="logarithmic", f_min_hz=2.0, f_max_hz=80.0, duration_s=2.0, amplitude_nm=4.0
    )
    ((index, rows),) = seen
    assert result.completed and result.stats.lost_samples == 0 and np.array_equal(index, np.arange(2000))
    excitation = rows[:, ad.channel_names.index("excitation")]
    # computed from what the drive stores: the sweep without the host's fade in and out
    plain = sig.chirp(4.0, 2.0, 80.0, 2.0, FS, method="logarithmic")
    assert np.allclose(excitation, plain, atol=1e-9)
    assert np.allclose(excitation[200:-200], x[200:-200], atol=1e-9) and not np.allclose(excitation[:50], x[:50])
    kinds = [e["kind"] for e in result.events]
    assert "excitation_computed" in kinds and "excitation_differs" in kinds  # the host's samples are faded
    # the drive played it: the torque it measured follows the sweep (CST, torque actual in per mille of 1 N*m)
    torque = rows[:, ad.channel_names.index("torque_nm")]
    assert np.max(np.abs(torque - excitation)) < 0.05
    fw = emu.server.firmware
    assert not emu.drive.enabled and fw.recorder.gen_state == 0  # stopped, generator idle


def test_the_generator_feeds_the_torque_offset_while_the_drive_holds_its_position(twin):
    ad, emu, cfg = twin(PRBS)
    assert ad.desc.modes["torque_injection"].setpoint == "torque_offset"
    ad.configure(FS, "torque_injection")
    full = replace(
        cfg,
        excitation=replace(
            cfg.excitation, kind="prbs", mode="torque_injection", amplitude_nm=2.0, register_length=9, duration_s=1.5
        ),
    )
    x = build_excitation(full).samples
    ad.set_excitation_recipe(excitation_recipe(full))
    seen = []
    result = ad.stream(x, lambda i, rows: seen.append(rows))
    rows = np.vstack(seen)
    assert result.completed and len(rows) == len(x) and result.stats.lost_samples == 0
    assert np.array_equal(rows[:, ad.channel_names.index("excitation")], x)
    velocity = rows[:, ad.channel_names.index("velocity_mps")]
    position = rows[:, ad.channel_names.index("position_m")]
    # the offset shook the axis, and the position loop (CSP at the position at enable) kept it in place
    assert np.std(velocity) > 1e-4 and np.ptp(position) < 5e-3
    assert abs(emu.drive.torque_offset_nm) < 1e-12  # nothing of the generator left in the loop after the run


@pytest.mark.parametrize(
    "drive, excitation, key",
    [
        (PRBS, {"kind": "multisine", "duration_s": 2.0}, "excitation.kind"),
        (PRBS, {"kind": "prbs", "amplitude_nm": 25.0, "duration_s": 2.0}, "excitation.amplitude_nm"),
        (PRBS, {"kind": "prbs", "register_length": 6, "duration_s": 0.5}, "excitation.register_length"),
        (PRBS, {"kind": "prbs", "register_length": 10, "duration_s": 9.0}, "excitation.duration_s"),
        (
            SWEEP,
            {"kind": "chirp", "f_max_hz": 300.0, "chirp_method": "logarithmic", "duration_s": 1.0},
            "excitation.f_max_hz",
        ),
        (SWEEP, {"kind": "chirp", "chirp_method": "linear", "duration_s": 1.0}, "excitation.chirp_method"),
        (SWEEP, {"kind": "prbs", "duration_s": 1.0}, "excitation.kind"),
    ],
)
def test_a_recipe_the_generator_cannot_play_is_refused_before_anything_moves(twin, drive, excitation, key):
    ad, emu, cfg = twin(drive)
    ad.configure(FS, "torque")
    fw = emu.server.firmware
    ticks = emu.drive.tick
    full = replace(cfg, excitation=replace(cfg.excitation, **excitation))
    ad.set_excitation_recipe(excitation_recipe(full))
    with pytest.raises(ConfigError) as info:
        ad.stream(build_excitation(full).samples, lambda i, rows: None)
    assert info.value.key == key and "generator" in str(info.value) and drive.name in str(info.value)
    assert emu.drive.tick == ticks and not emu.drive.enabled and fw.recorder.rec_state == 0


def test_a_run_without_a_recipe_is_refused(twin):
    ad, _, _ = twin(PRBS)
    ad.configure(FS, "torque")
    with pytest.raises(ConfigError, match=r"\[device.acquisition\].*no excitation recipe"):
        ad.stream(np.zeros(100), lambda i, rows: None)


def test_a_recording_that_ends_early_is_delivered_counted_and_named(twin):
    ad, emu, cfg = twin(PRBS, capture_stops_after_s=1.5)
    seen = []
    ad.configure(FS, "torque")
    full = replace(cfg, excitation=replace(cfg.excitation, kind="prbs", register_length=10, duration_s=3.1))
    x = build_excitation(full).samples
    ad.set_excitation_recipe(excitation_recipe(full))
    with pytest.raises(DeviceError, match=r"only 1500 of 4092 samples.*0x2500:6 \(.*Recorded samples\)"):
        ad.stream(x, lambda i, rows: seen.append(i))
    assert np.array_equal(np.concatenate(seen), np.arange(1500))  # what it holds, from 0, nothing filled
    stats = ad.last_result.stats
    assert stats.samples == 1500 and stats.lost_samples == 4092 - 1500
    assert any(e["kind"] == "capture_short" for e in ad.last_result.events)
    assert not emu.drive.enabled


def test_a_drive_silent_during_the_upload_is_named(twin):
    ad, emu, cfg = twin(PRBS)
    transfer = ad.sdo._block_transfer

    def gone(addr, *args):  # the drive is unplugged just before its buffer is read
        emu.close()
        return transfer(addr, *args)

    ad.sdo._block_transfer = gone
    with pytest.raises(DeviceError, match=r"0x2502:0 \(Recorder data buffer\)"):
        _play(ad, cfg, kind="prbs", register_length=10, duration_s=1.0)


def test_a_buffer_shorter_than_the_recorded_count_is_named(twin):
    ad, emu, cfg = twin(SWEEP)
    rec = emu.server.firmware.recorder
    buffer = rec._buffer
    rec._buffer = lambda i: buffer(i)[:-20] if i == 2 else buffer(i)  # the drive lost the end of one channel
    with pytest.raises(DeviceError, match=r"buffer 0x2503:3 \(.*Channel 3 data\) holds 19\d\d samples; 2000 were"):
        _play(ad, cfg, kind="sine", frequency_hz=10.0, duration_s=2.0)


def test_a_fault_ends_the_run_after_what_was_recorded(twin):
    ad, emu, cfg = twin(PRBS, drive_fault_after_s=1.0)
    with pytest.raises(DeviceError, match=r"0x4310"):
        _play(ad, cfg, kind="prbs", register_length=10, duration_s=3.1)
    assert ad.last_result.stats.samples >= 900 and not emu.drive.enabled


# --- the vocabulary --------------------------------------------------------------------------------------


def _sections(drive: VendorDrive, tmp_path: Path):
    import tomllib

    folder = write_vendor_drive(tmp_path, drive)
    return folder, tomllib.loads((folder / "driver.toml").read_text())


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda r, g: r.pop("recorded"), "canopen.recorder.recorded"),
        (lambda r, g: r.update(max_samples=0), "canopen.recorder.max_samples"),
        (lambda r, g: r.update(sample_periods=[0, 2]), "canopen.recorder.sample_periods"),
        (lambda r, g: r.update(buffers=["0x2502"]), "canopen.recorder.buffer"),
        (lambda r, g: r.update(channel_encoding="index_subindex"), "canopen.recorder.channel_encoding"),
        (lambda r, g: r.update(states={"idle": 0, "done": 3}), "canopen.recorder.states.waiting"),
        (lambda r, g: g["kinds"].update(noise={"code": 4}), "canopen.generator.kinds.noise"),
        (lambda r, g: g["kinds"]["prbs"].pop("clock_divider"), "canopen.generator.kinds.prbs.clock_divider"),
        (
            lambda r, g: g["kinds"]["prbs"]["amplitude"].update(scale="newton"),
            "canopen.generator.kinds.prbs.amplitude.scale",
        ),
        (lambda r, g: g["kinds"]["prbs"].update(taps={"10": [12]}), "canopen.generator.kinds.prbs.taps.10"),
        (lambda r, g: g.update(targets={"target_position": 1}), "canopen.generator.targets"),
        (lambda r, g: g.update(output="0x2502"), "canopen.generator.output"),  # a DOMAIN, not a number
        (lambda r, g: r.update(state="0x2500:1"), None),  # rw is readable: accepted
        (lambda r, g: r.update(control="0x2500:7"), "canopen.recorder.control"),  # const: the host cannot write it
        (lambda r, g: r.update(buffer="0x2500:6"), "canopen.recorder.buffer[0]"),  # a number, not a DOMAIN
        # keys a table does not know are refused, as in every table of a driver file (a typo is not ignored)
        (lambda r, g: r.update(block_transfers=False), "canopen.recorder.block_transfers"),
        (lambda r, g: g.update(output_scales="torque"), "canopen.generator.output_scales"),
        (lambda r, g: g["kinds"]["prbs"]["amplitude"].update(mx=3.0), "canopen.generator.kinds.prbs.amplitude.mx"),
        (lambda r, g: g.update(output_scale=float("inf")), "canopen.generator.output_scale"),  # a finite scale
        (lambda r, g: g.update(output_scale=True), "canopen.generator.output_scale"),  # a bool is no number
        (lambda r, g: g["targets"].update(target_torque=70000), "canopen.generator.targets.target_torque"),
        (
            lambda r, g: r["triggers"].update(generator=-1) if "triggers" in r else r.update(triggers={"immediate": 0}),
            "canopen.recorder.triggers.generator",
        ),
        (lambda r, g: g["kinds"]["prbs"].update(seed="0x35"), None),  # integer text: a register state
        (lambda r, g: g["kinds"]["prbs"].update(seed=0), "canopen.generator.kinds.prbs.seed"),
    ],
)
def test_vocabulary_errors_name_the_key_and_the_driver_file(tmp_path, edit, key):
    folder, sections = _sections(PRBS, tmp_path)
    edit(sections["canopen"]["recorder"], sections["canopen"]["generator"])
    od = load_object_dictionary(load_driver(folder), 1)
    source = str(folder / "driver.toml")
    if key is None:
        assert parse_recorder(sections, source, od) is not None
        return
    with pytest.raises(ConfigError) as info:
        parse_recorder(sections, source, od)
    assert info.value.key == key and info.value.file == source


def test_drivers_check_finds_a_recorder_object_missing_from_the_eds(tmp_path):
    folder = write_vendor_drive(tmp_path, PRBS)
    assert check_driver_folder(folder).ok
    toml = folder / "driver.toml"
    toml.write_text(toml.read_text().replace('buffer = "0x2502"', 'buffer = "0x2590"'))
    report = check_driver_folder(folder)
    assert not report.ok
    assert any(
        "[canopen.recorder.buffer[0]] object 0x2590:0 is not in the EDS" in e and str(toml) in e for e in report.errors
    )
    with pytest.raises(ConfigError, match=r"canopen.recorder.buffer\[0\]"):  # and the driver does not load
        load_driver(folder)


def test_a_drive_without_a_recorder_refuses_recorder_acquisition(tmp_path):
    folder = write_vendor_drive(tmp_path, VendorDrive("acme-plain"))
    driver = load_driver(folder)
    cfg = load_config(CONFIG)
    emu = start(replace(cfg.emulator, time_scale=20.0), driver, replace(cfg.device, driver=str(folder)))
    try:
        ad = CanopenDriveAdapter.open_device(replace(emu.device, acquisition="recorder", timeout_s=0.5), driver)
        try:
            with pytest.raises(ConfigError, match=r"\[device.acquisition\].*no \[canopen.recorder\]"):
                ad.configure(FS, "torque")
        finally:
            ad.close()
    finally:
        emu.close()


def test_more_channels_than_the_recorder_has_slots_are_refused_by_the_adapter_and_the_check_alike(tmp_path):
    from hilident.adapters.canopen.common import ChannelCodec
    from hilident.adapters.canopen.recorder import check_recorder_channels
    from hilident.protocol.canopen_objects import CanopenDescription
    from hilident.protocol.canopen_pdo_plan import RunChannel, recorder_problems

    folder = write_vendor_drive(tmp_path, PRBS)
    driver = load_driver(folder)
    desc = CanopenDescription.from_sections(
        driver.sections, str(folder / "driver.toml"), load_object_dictionary(driver)
    )
    slots = len(desc.recorder.recorder.channels)
    codecs = [ChannelCodec(f"c{i}", "", "velocity", ObjectAddress(0x606C, 0), 0x0004, 1.0) for i in range(slots)]
    check_recorder_channels(desc, driver, codecs)  # as many as it has: taken
    one_more = [*codecs, ChannelCodec("host", "", None, None, 0x0004, 1.0)]  # the generator output records it
    with pytest.raises(ConfigError) as info:
        check_recorder_channels(desc, driver, one_more)
    assert info.value.key == "run.channels" and f"{slots + 1} recorded channels" in str(info.value)
    (problem,) = recorder_problems(desc, [RunChannel(c.name, c.address) for c in one_more])
    assert problem in str(info.value)  # drivers check says what the adapter says


def test_the_twins_generator_refuses_what_its_description_refuses(twin):
    # written past the host's checks, straight by SDO: the drive answers as a drive does
    ad, _, _ = twin(PRBS)
    with pytest.raises(DeviceError, match=r"0x2511:1 .*PRBS amplitude.*0x06090031"):
        ad.sdo.write_object(ObjectAddress(0x2511, 1), 25000)  # 25 N*m in per mille of 1 N*m: above its 20 N*m
    with pytest.raises(DeviceError, match=r"0x2510:3 .*Signal type.*0x06090030"):
        ad.sdo.write_object(ObjectAddress(0x2510, 3), 7)  # no such signal
    with pytest.raises(DeviceError, match=r"0x2500:4 .*Sampling period.*0x06090030"):
        ad.sdo.write_object(ObjectAddress(0x2500, 4), 3)  # not an allowed sample period
    with pytest.raises(DeviceError, match=r"0x2501:1 .*0x06040041"):
        ad.sdo.write_object(ObjectAddress(0x2501, 1), 0x60400010)  # the controlword is not a sampled signal
    with pytest.raises(DeviceError, match=r"0x2510:1 .*0x08000022"):
        ad.sdo.write_object(ObjectAddress(0x2510, 1), 1)  # start while the power stage is off


def test_the_driver_can_make_the_recorder_its_default(tmp_path):
    folder = write_vendor_drive(tmp_path, PRBS)
    toml = folder / "driver.toml"
    toml.write_text(toml.read_text().replace("[canopen]\n", '[canopen]\ndefault_acquisition = "recorder"\n'))
    driver = load_driver(folder)
    cfg = load_config(CONFIG)
    emu = start(replace(cfg.emulator, time_scale=20.0), driver, replace(cfg.device, driver=str(folder)))
    try:
        ad = CanopenDriveAdapter.open_device(replace(emu.device, acquisition="auto", timeout_s=0.5), driver)
        ad.close()
    finally:
        emu.close()
    assert ad.acquisition == "recorder"
    # without a recorder to default to, the description is refused, naming the key and the file
    plain = write_vendor_drive(tmp_path, VendorDrive("acme-plain"))
    toml = plain / "driver.toml"
    toml.write_text(toml.read_text().replace("[canopen]\n", '[canopen]\ndefault_acquisition = "recorder"\n'))
    with pytest.raises(ConfigError) as info:
        load_driver(plain)
    assert info.value.key == "canopen.default_acquisition" and info.value.file == str(toml)


def test_the_twins_generator_feeds_the_torque_set_point_only_in_cst(twin):
    ad, _, _ = twin(PRBS)
    ad.configure(FS, "torque_injection")  # CSP: the torque set-point is not the loop's input
    ad.enable()
    ad.sdo.write_object(ObjectAddress(0x2510, 3), 1)  # PRBS
    ad.sdo.write_object(ObjectAddress(0x2510, 4), 1)  # target: the torque set-point
    with pytest.raises(DeviceError, match=r"0x2510:1 .*0x08000022"):
        ad.sdo.write_object(ObjectAddress(0x2510, 1), 1)
    ad.safe_stop()
