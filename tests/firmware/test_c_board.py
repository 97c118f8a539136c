"""hilident against the reference C firmware: the shipped gantry session on ``posix-sim``'s simulated axis.

The C board is built from ``drivers/myrio-board/firmware`` with its Makefile, started on a TCP port of
127.0.0.1, and ``hilident run`` runs the shipped ``configs/emulated-gantry.toml`` session against it with
only ``[device] port`` changed: a board hilident did not emulate, whose plant it has never seen. The
session must find that plant's mode, fit its friction, upload a notch the board reads back, verify it,
and lose nothing on the line. The same board built with the address and undefined-behaviour sanitizers
then runs a short session and takes hostile bytes without a finding.
"""

from __future__ import annotations

import json
import math
import random
import re
import socket
import time
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomli_w

from hilident.config.tables import parse_config
from hilident.filters.biquad import Biquad
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame
from support.c_board import FIRMWARE, CBoard, plant
from support.loop_truth import assert_loop_figures_match, true_loop_figures
from support.twins import CONFIGS, assert_friction_matches, finish, host

pytestmark = pytest.mark.twin

SHIPPED = CONFIGS / "emulated-gantry.toml"
#: Simulated seconds per wall second, as the shipped config's own twin runs ([emulator] time_scale = 4.0).
TIME_SCALE = "4"
#: The whole shipped session runs at half that: the host then takes 2000 samples a second, which it keeps up
#: with while the other tests of a CI run load both cores (at 4x the friction legs came out loose there).
SESSION_TIME_SCALE = "2"


def session_config(url: str, folder: Path, name: str, **sections: dict) -> Path:
    """The shipped gantry session pointed at ``url``; ``sections`` update its tables."""
    raw = tomllib.loads(SHIPPED.read_text())
    raw["device"]["port"] = url
    # the configured friction legs only: the test's added rounds are tests/test_friction_extension.py's (as
    # tests/conftest.py keeps them out of the sessions run in-process)
    raw.setdefault("friction_test", {}).setdefault("max_rounds", 1)
    for section, values in sections.items():
        raw.setdefault(section, {}).update(values)
    path = folder / f"{name}.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def run_session(board: CBoard, folder: Path, name: str, **sections: dict) -> dict:
    """``hilident run --yes`` against ``board``; its summary.json (the run must succeed)."""
    out = folder / name
    rc, err = finish(host(session_config(board.url, folder, name, **sections), out), timeout=400)
    assert rc == 0, err
    assert board.alive()
    return json.loads((out / "summary.json").read_text())


def assert_clean_stream(summary: dict) -> None:
    stream = summary["stream"]
    lost = {k: stream[k] for k in ("lost_frames", "lost_blocks", "lost_samples", "corrupt_frames", "out_of_order")}
    assert not any(lost.values()), lost
    assert stream["samples"] > 0


def test_the_shipped_session_finds_fits_and_notches_the_c_boards_gantry(posix_sim, tmp_path):
    truth = plant(posix_sim)
    board = CBoard(posix_sim, "--time-scale", SESSION_TIME_SCALE)
    try:
        # two periods of the shipped multisine, not four: the figures below hold on two, in half the time
        summary = run_session(board, tmp_path, "gantry", excitation={"duration_s": 8.0})
    finally:
        board_rc, board_err = board.stop()
    assert board_rc == 0, board_err
    assert not summary["device"]["emulated"] and summary["device"]["port"] == board.url
    assert summary["connect"]["found_state"] == "IDLE"

    found = summary["resonances"][0]["frequency_hz"]
    assert abs(found - truth["mode_hz"]) / truth["mode_hz"] < 0.005, (found, truth["mode_hz"])

    # as for the Python twin: within 3 standard errors of the fit (at least 5 %), which knows them to 15 %
    assert_friction_matches(summary["friction"], SimpleNamespace(Fc=truth["fc_nm"], Fv=truth["fv_nm_per_mps"]))

    upload = summary["upload"]
    assert upload["written"] and upload["verified_readback"]
    assert upload["slots"] and all(slot["matches"] for slot in upload["slots"])
    assert summary["verification"]["band_reduction_db"] >= 20.0, summary["verification"]

    assert_loop_matches_the_c_gantry(summary, truth)
    assert_clean_stream(summary)


def assert_loop_matches_the_c_gantry(summary: dict, truth: dict[str, float]) -> None:
    """The board's LOOP (board_config.h's power-up gains, no current loop and no delay of its own: firmware
    README) and the margins hilident predicts from the plant it identified, within 1 dB and 5 degrees of those
    of the C gantry's own plant (``--print-plant``) with those gains."""
    config = (FIRMWARE / "core" / "board_config.h").read_text()

    def define(name: str) -> float:
        found = re.search(rf"^#define {name} (\S+)", config, re.MULTILINE)
        assert found, f"board_config.h defines no {name}"
        return float(found.group(1).replace("INFINITY", "inf"))

    def power_up(name: str) -> float:
        return sb.float32(define(f"BOARD_LOOP_{name.upper()}"))

    parameters = {name: power_up(name) for name in sb.LOOP_FIELDS}
    assert parameters["current_loop_hz"] == math.inf and parameters["delay_ticks"] == 0.0
    # summary.json spells an infinity null (JSON has none)
    assert summary["loop"]["parameters"] == {n: v if math.isfinite(v) else None for n, v in parameters.items()}
    plant_table = {k: truth[k] for k in ("m1_kg", "m2_kg", "k_n_per_m", "d_ns_per_m", "c_n_per_nm")}
    emulator = parse_config(
        "[emulator.plant]\nmodel = 'two_mass'\n"
        + "".join(f"{key.split('_')[0]} = {value!r}\n" for key, value in plant_table.items())
    ).emulator
    tuning = SimpleNamespace(loop_rate_hz=define("BOARD_LOOP_RATE_HZ"), **parameters)
    notches = [Biquad(np.array(n["b"]), np.array(n["a"])) for n in summary["notch_filters"]]
    assert_loop_figures_match(summary["loop"], true_loop_figures(emulator, tuning, notches))


def board_status(url: str) -> sb.Status:
    """STATUS of the board at ``url``, asked on a new connection (whatever else is on the line is skipped)."""
    port = int(url.rsplit(":", 1)[1])
    decoder = FrameDecoder()
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(encode_frame(sb.encode(sb.StatusRequest(), 1)))
        s.settimeout(0.2)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            try:
                data = s.recv(65536)
            except TimeoutError:
                continue
            for payload in decoder.feed(data):
                if payload[1] == sb.MsgType.STATUS:
                    return sb.decode(payload)[1]
    raise AssertionError(f"{url}: no STATUS")


QUICK = {
    "friction_test": {"enabled": False},
    "excitation": {"period_s": 2.0, "duration_s": 4.0, "amplitude_nm": 8.0},
}


def test_a_killed_host_leaves_the_c_board_stopped_by_its_watchdog(posix_sim, tmp_path):
    """SIGKILL of a host mid-run: within 1 s the board stops the axis itself and latches FAULT WATCHDOG; the
    next session must clear it (``--clear-fault``) and then succeeds."""
    truth = plant(posix_sim)
    board = CBoard(posix_sim, "--time-scale", TIME_SCALE)
    try:
        out = tmp_path / "killed"
        long_run = {**QUICK, "excitation": {**QUICK["excitation"], "duration_s": 60.0}}
        config = session_config(board.url, tmp_path, "killed", **long_run)
        proc = host(config, out)
        deadline = time.monotonic() + 60
        while not (out / "identification.h5").exists():
            assert proc.poll() is None and time.monotonic() < deadline, finish(proc)[1]
            time.sleep(0.05)
        time.sleep(0.5)
        proc.kill()
        finish(proc)
        time.sleep(1.5)  # the watchdog's second, and a margin
        status = board_status(board.url)
        assert (status.state, status.fault) == (sb.State.FAULT, sb.FaultCode.WATCHDOG), status
        assert status.samples_produced > 0

        refused = tmp_path / "refused"
        rc, err = finish(host(session_config(board.url, tmp_path, "refused", **QUICK), refused), timeout=120)
        assert rc == 4 and "WATCHDOG" in err, err
        summary = run_session(board, tmp_path, "second", **QUICK, device={"allow_fault_reset": True})
    finally:
        board_rc, board_err = board.stop()
    assert board_rc == 0, board_err
    assert summary["connect"]["faults_cleared"]
    found = summary["resonances"][0]["frequency_hz"]
    assert abs(found - truth["mode_hz"]) / truth["mode_hz"] < 0.005, (found, truth["mode_hz"])


# --- the sanitizer build ---------------------------------------------------------------------------------------


def hostile_bytes(url: str) -> tuple[list, FrameDecoder]:
    """Garbage, an oversize run, damaged frames and malformed payloads on the board's line, then IDENTIFY:
    the board must still answer, with frames that decode."""
    port = int(url.rsplit(":", 1)[1])
    rng = random.Random(31)
    frames = [
        bytes(rng.randrange(256) for _ in range(5000)) + b"\x00",  # line noise
        b"\x07" * 70_000 + b"\x00",  # more than 65 536 bytes without a delimiter
        encode_frame(sb.encode(sb.Ping(), 1))[:-3] + b"\x55\x00",  # a damaged CRC
        encode_frame(b"\x01"),  # a payload shorter than the header
        encode_frame(bytes([2, sb.MsgType.PING, 2, 0])),  # another protocol version
        encode_frame(bytes([1, 0x42, 3, 0])),  # an unknown type
        encode_frame(bytes([1, sb.MsgType.ACK, 4, 0, 1])),  # a board->host type
        encode_frame(bytes([1, sb.MsgType.CONFIGURE, 5, 0]) + bytes(11) + b"\xff"),  # 255 channels announced
        encode_frame(bytes([1, sb.MsgType.EXCITATION, 6, 0]) + bytes(6) + bytes(3)),  # values that do not add up
        encode_frame(bytes([1, sb.MsgType.EXCITATION, 7, 0, 0, 0, 0, 0, 0xFF, 0xFF]) + bytes(4 * 0xFFFF)[:60_000]),
        encode_frame(bytes([1, sb.MsgType.WRITE_FILTER, 8, 0, 200])),  # too short
    ]
    # random bodies for every request but the writes (a random notch or gain left in place would change the plant)
    kinds = [t for t in sb.MsgType if t < 0x80 and t not in (sb.MsgType.WRITE_FILTER, sb.MsgType.WRITE_LOOP)]
    assert sb.MsgType.READ_LOOP in kinds
    frames += [encode_frame(bytes([1, rng.choice(kinds), 9, 0]) + rng.randbytes(rng.randrange(40))) for _ in range(200)]
    frames.append(encode_frame(sb.encode(sb.Identify(), 10)))
    decoder = FrameDecoder()
    answers: list = []
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        for frame in frames:
            s.sendall(frame)
        s.settimeout(0.2)
        deadline = time.monotonic() + 30  # a sanitized build on a loaded machine works through them slowly
        while time.monotonic() < deadline and not any(isinstance(m, sb.Identity) for m in answers):
            try:
                data = s.recv(65536)
            except TimeoutError:
                continue
            if not data:
                break
            for payload in decoder.feed(data):
                if payload[1] != sb.MsgType.SAMPLES:
                    answers.append(sb.decode(payload)[1])
    return answers, decoder


def test_the_sanitized_board_runs_a_session_and_takes_hostile_bytes_without_a_finding(sanitized_sim, tmp_path):
    truth = plant(sanitized_sim)
    board = CBoard(sanitized_sim, "--time-scale", TIME_SCALE, sanitized=True)
    try:
        answers, decoder = hostile_bytes(board.url)
        assert any(isinstance(m, sb.Identity) for m in answers), answers[-5:]
        assert decoder.stats.corrupt == 0
        # the sanitized build answers slower, and a busy machine slower still: the host waits 10 s, not 2
        summary = run_session(board, tmp_path, "short", device={"timeout_s": 10.0}, **QUICK)
    finally:
        board_rc, board_err = board.stop()
    assert board_rc == 0 and "runtime error" not in board_err and "Sanitizer" not in board_err, board_err
    found = summary["resonances"][0]["frequency_hz"]
    assert abs(found - truth["mode_hz"]) / truth["mode_hz"] < 0.005, (found, truth["mode_hz"])
    assert summary["upload"]["verified_readback"]
    assert_clean_stream(summary)
