"""Every ending of a session, over every transport: the ending matrix.

One test class, parametrised over the transports (python-can's back-to-back
style): the twin is served in this process on a real transport (a
pseudo-terminal, a raw TCP line, Modbus TCP, Modbus RTU on a pseudo-terminal,
CANopen behind socketcand), and ``hilident run`` runs in another process as it
would on the bench. Each ending (SIGTERM, SIGHUP, SIGINT twice, SIGKILL of
the host, the device vanishing, a full disk, a limit trip) is checked the same
way: the twin's own state shows the axis stopped, the exit code is the
documented one, every recording is readable with the right status, and a
second session on the twin then succeeds and finds the right resonance.
Endings the host handles whatever link carries its frames (the signals, a
full disk) and the device-side net after SIGKILL (the board's watchdog, the
Modbus timeout, the heartbeat consumer) run once per adapter; the ones where
the link matters (the device vanishing, a limit trip) on every link.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
import tomllib
from pathlib import Path

import pytest

from hilident.io.recording import read_run
from support.twins import HOST_TIMEOUT_S, TRANSPORTS, Twin, finish, host, wait_until

#: Exit codes the bench guide documents (docs/bench-guide.md).
EXIT = {
    "sigterm": 143,
    "sighup": 129,
    "sigint_twice": 130,
    "sigkill": -signal.SIGKILL,
    "device_vanishes": 4,
    "disk_full": 3,
    "limit_trip": 5,
}

#: How long the twin may keep the axis enabled after the host is gone, s: the device-side net
#: (serial: the board's 1 s watchdog; CANopen and Modbus: host_timeout_s) plus the twin's clock.
NET_TIMEOUT_S = {"serial": 1.0, "modbus": HOST_TIMEOUT_S, "canopen": HOST_TIMEOUT_S}
TOLERANCE_S = 0.6


#: One link per adapter, for the endings the host handles the same way whatever carries its frames (a signal, a
#: full disk): the adapter's stop path is what differs, not the link below it.
ADAPTERS = [t for t in TRANSPORTS if (t[0], t[1]) in {("serial", "pty"), ("modbus", "tcp"), ("canopen", "socketcand")}]


def _serve(request, tmp_path):
    transport, link, config = request.param
    t = Twin(transport, link, config, tmp_path)
    yield t
    t.close()


@pytest.fixture(params=TRANSPORTS, ids=[f"{t}-{link}" for t, link, _ in TRANSPORTS])
def twin(request, tmp_path):
    yield from _serve(request, tmp_path)


@pytest.fixture(params=ADAPTERS, ids=[f"{t}-{link}" for t, link, _ in ADAPTERS])
def adapter_twin(request, tmp_path):
    yield from _serve(request, tmp_path)


class TestEndingMatrix:
    """One class over every transport: each ending leaves a stopped axis, true files and a device ready to go."""

    def _start_and_wait_for_motion(self, twin, tmp_path, name="first", fsize_limit=None, **sections):
        """A first session, long enough to be ended mid-run, once the twin's drive is enabled."""
        out = tmp_path / name
        sections.setdefault("excitation", {"duration_s": 16.0})
        proc = host(twin.host_config(name, **sections), out, fsize_limit=fsize_limit)
        wait_until(lambda: twin.enabled, 60, proc)
        return proc, out

    def _finish(self, proc, timeout=60):
        return finish(proc, timeout)

    def _second_session_finds_the_resonance(self, twin, tmp_path, clear_fault: bool):
        out = tmp_path / "second"
        config = twin.host_config("second")
        proc = host(config, out, *(["--clear-fault"] if clear_fault else []))
        rc, err = self._finish(proc, timeout=120)
        assert rc == 0, err
        summary = json.loads((out / "summary.json").read_text())
        found = summary["resonances"][0]["frequency_hz"]
        assert abs(found - twin.truth_hz) / twin.truth_hz < 0.005, (found, twin.truth_hz)
        assert not twin.enabled

    def _recording(self, out: Path):
        run = read_run(out / "identification.h5")
        return run

    @pytest.mark.parametrize("ending", ["sigterm", "sighup", "sigint_twice"])
    def test_signal(self, adapter_twin, tmp_path, ending):
        twin = adapter_twin
        proc, out = self._start_and_wait_for_motion(twin, tmp_path)
        time.sleep(0.8)  # samples flowing for longer than a flush interval
        sent = time.monotonic()
        if ending == "sigint_twice":
            proc.send_signal(signal.SIGINT)
            time.sleep(0.001)
            proc.send_signal(signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM if ending == "sigterm" else signal.SIGHUP)
        stopped = wait_until(lambda: not twin.enabled, 5)
        rc, err = self._finish(proc)
        assert rc == EXIT[ending], err
        assert stopped - sent < 2.0  # the host's own stop: bench/stop_latency.py measures it (target 100 ms)
        run = self._recording(out)
        assert run.status == "aborted" and "interrupted" in run.reason
        assert run.n_samples > 0
        assert "Traceback" not in err
        if ending == "sigterm":  # the three signals share one stop path: one second session shows the device ready
            # no latched fault (a watchdog would have latched one): the next session needs no --clear-fault
            self._second_session_finds_the_resonance(twin, tmp_path, clear_fault=False)

    def test_sigkill_the_device_stops_itself(self, adapter_twin, tmp_path):
        twin = adapter_twin  # the device-side net is the adapter's (watchdog, timeout, heartbeat), not the link's
        proc, out = self._start_and_wait_for_motion(twin, tmp_path)
        time.sleep(0.8)
        proc.kill()
        killed = time.monotonic()
        stopped = wait_until(lambda: not twin.enabled, 10)
        rc, _ = self._finish(proc)
        assert rc == EXIT["sigkill"]
        assert stopped - killed < NET_TIMEOUT_S[twin.transport] + TOLERANCE_S
        run = self._recording(out)
        assert run.status == "running" and run.n_samples > 0  # a crashed file: readable, and says so
        self._second_session_finds_the_resonance(twin, tmp_path, clear_fault=True)

    def test_device_vanishes(self, twin, tmp_path):
        proc, out = self._start_and_wait_for_motion(twin, tmp_path)
        time.sleep(0.5)
        twin.close()
        rc, err = self._finish(proc)
        assert rc == EXIT["device_vanishes"], err
        assert not twin.enabled
        assert "Traceback" not in err
        assert self._recording(out).status == "aborted"
        # no second session: the device is gone, and a fresh one on another port would show nothing of this ending

    def test_disk_full(self, adapter_twin, tmp_path):
        twin = adapter_twin
        proc, out = self._start_and_wait_for_motion(twin, tmp_path, fsize_limit=2_600_000)
        rc, err = self._finish(proc)
        assert rc == EXIT["disk_full"], err
        assert "Traceback" not in err
        assert not twin.enabled
        run = self._recording(out)
        assert run.status == "aborted"
        assert run.n_samples > 0 and not (run.samples["time_s"][1:] == 0).any()  # nothing written as zeros
        self._second_session_finds_the_resonance(twin, tmp_path, clear_fault=False)

    def test_limit_trip(self, twin, tmp_path):
        # the trip may come within milliseconds of the enable: nothing waits to see the axis enabled first
        out = tmp_path / "first"
        config = twin.host_config("first", excitation={"duration_s": 16.0}, limits={"velocity_mps": 0.004})
        rc, err = self._finish(host(config, out))
        assert rc == EXIT["limit_trip"], err
        assert not twin.enabled
        run = self._recording(out)
        assert run.status == "aborted"
        self._second_session_finds_the_resonance(twin, tmp_path, clear_fault=True)


def test_a_second_ctrl_c_after_the_stop_keeps_the_exit_code(tmp_path):
    """The second Ctrl-C may land after the cleanup finished: the exit code is still 130, not a death by SIGINT."""
    import os
    import sys
    import textwrap

    script = textwrap.dedent("""
        import os, signal, sys
        from hilident.cli import main as cli

        def run(args):  # a session that a Ctrl-C ends
            os.kill(os.getpid(), signal.SIGINT)

        cli._run = run
        code = cli.main(["run", "any.toml"])
        os.kill(os.getpid(), signal.SIGINT)  # the second one, after the session's handlers are gone
        sys.exit(code)
    """)
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ),
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert done.returncode == 130, done.stderr


def test_nohup_keeps_sighup_ignored(tmp_path):
    """A session started with SIGHUP ignored (``nohup``) is not ended by it; SIGTERM still ends it."""
    import os
    import sys
    import textwrap

    script = textwrap.dedent("""
        import os, signal, sys, time
        from hilident.cli import main as cli

        def run(args):  # a session that gets a SIGHUP, then a SIGTERM
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
            print("still running after SIGHUP", flush=True)
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            return 0

        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        cli._run = run
        sys.exit(cli.main(["run", "any.toml"]))
    """)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=dict(os.environ)
    )
    assert "still running after SIGHUP" in done.stdout
    assert done.returncode == 143, done.stderr


@pytest.fixture
def two_drives(tmp_path):
    """Two drives of one gantry on one CANopen bus behind socketcand, and a host config that runs them both."""
    import tomli_w

    from hilident.config.tables import parse_config
    from hilident.drivers.description import find_driver
    from hilident.emulator.factory import host_device_table, start_standalone
    from test_nodes_run import CONFIG

    text = CONFIG.replace("duration_s = 12.0", "duration_s = 40.0")
    assert text != CONFIG  # a long run, to end mid-way
    cfg = parse_config(text, "two-drives.toml")
    emu = start_standalone(cfg.emulator, find_driver(cfg.device.driver), cfg.device, "socketcand")
    raw = tomllib.loads(text)
    raw["device"] = host_device_table(emu.device) | {"host_timeout_s": HOST_TIMEOUT_S}
    config = tmp_path / "two-drives.toml"
    config.write_text(tomli_w.dumps(raw))
    yield emu, config
    emu.close()


def _two_drive_host(two_drives, tmp_path):
    emu, config = two_drives
    out = tmp_path / "first"
    proc = host(config, out)
    wait_until(lambda: all(d.enabled for d in emu.drives), 60, proc)
    time.sleep(0.8)  # samples flowing for longer than a flush interval
    return emu, proc, out


def test_sigterm_stops_both_drives_of_one_bus(two_drives, tmp_path):
    """The ending matrix's row of two drives on one CANopen bus (socketcand): SIGTERM switches both off together."""
    emu, proc, out = _two_drive_host(two_drives, tmp_path)
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    stops = [wait_until(lambda d=d: not d.enabled, 5) for d in emu.drives]
    rc, err = finish(proc)
    assert rc == EXIT["sigterm"], err
    assert "Traceback" not in err
    assert not any(d.enabled for d in emu.drives)
    assert max(stops) - sent < 2.0  # as the matrix: bench/stop_latency.py measures the host's stop
    assert max(stops) - min(stops) < 0.1, stops  # together: the second node is not left running
    run = read_run(out / "identification.h5")
    assert run.status == "aborted" and "interrupted" in run.reason and run.n_samples > 0
    assert {"torque_nm_node1", "torque_nm_node2"} <= set(run.samples)


def test_sigkill_both_drives_of_one_bus_stop_themselves(two_drives, tmp_path):
    """The host killed: each drive's heartbeat consumer switches it off, both within the timeout."""
    emu, proc, out = _two_drive_host(two_drives, tmp_path)
    proc.kill()
    killed = time.monotonic()
    stops = [wait_until(lambda d=d: not d.enabled, 10) for d in emu.drives]
    rc, _ = finish(proc)
    assert rc == EXIT["sigkill"]
    assert max(stops) - killed < NET_TIMEOUT_S["canopen"] + TOLERANCE_S
    run = read_run(out / "identification.h5")
    assert run.status == "running" and run.n_samples > 0  # a crashed file: readable, and says so
