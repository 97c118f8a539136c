"""``hilident init``: a commented configuration to start from, for one transport and driver.

The file runs against the driver's emulated twin as written (``port =
"emulator"``); every key a user must check before a real port is marked
``CHECK`` and carries its unit and what a safe value is. The values follow the
shipped ``configs/emulated-*.toml``; the sample rate, the excitation mode and
the friction test follow what the driver description declares.
"""

from __future__ import annotations

from pathlib import Path

from hilident.errors import ConfigError, UsageError

#: The driver ``hilident init --transport T`` writes a config for when no ``--driver`` is given.
DEFAULT_DRIVERS = {"serial": "myrio-board", "canopen": "canopen-servo", "modbus": "modbus-servo"}
TRANSPORTS = tuple(DEFAULT_DRIVERS)

_PORT_NOTE = {
    "serial": (
        '"emulator", or the board\'s port: /dev/ttyUSB0, /dev/ttyACM0, COM3,',
        "or a pyserial URL (socket://HOST:PORT, rfc2217://HOST:PORT); hilident ports lists the ports found",
    ),
    "canopen": (
        '"emulator", or the python-can channel: can0 (socketcan), PCAN_USBBUS1 (pcan),',
        "0 (kvaser), HOST:PORT/CHANNEL (socketcand); hilident ports lists the CAN channels found",
    ),
    "modbus": (
        '"emulator", or tcp://HOST:PORT for Modbus TCP (usually port 502),',
        "else the RTU serial port (/dev/ttyUSB0, COM3); hilident ports lists the serial ports found",
    ),
}

_TRANSPORT_TABLES = {
    "serial": "",
    "canopen": """\
[device.canopen]
can_interface = "socketcan"      # CHECK: python-can interface: socketcan, pcan, kvaser, socketcand, ... (ignored
                                 #        by the emulator, which runs a virtual bus of its own)
node_id = 1                      # CHECK: the drive's CANopen node id, 1..127
trace = ""                       # "asc" or "blf": a CAN trace of each run beside its recording

""",
    "modbus": """\
[device.modbus]
device_id = 1                    # CHECK: the drive's Modbus unit (slave) id, 0..247
parity = "E"                     # RTU only: "N", "E" or "O" (the drive's setting)
stopbits = 1                     # RTU only: 1 or 2

""",
}


_EMULATOR_LINK = {
    "serial": 'link = "pty"                     # the twin on a pseudo-terminal, as a USB board\n',
    "modbus": 'link = "tcp"                     # the twin as Modbus TCP on 127.0.0.1 ("pty": RTU)\n',
    "canopen": "",
}
_FRICTION_NOTE = {
    True: "constant-speed legs both ways, then a Stribeck friction fit",
    False: "off: the driver has no velocity or position mode for the legs",
}


def starter_config(transport: str | None = None, driver_name: str | None = None) -> str:
    """The text of a commented configuration for ``transport`` and ``driver_name``.

    Parameters
    ----------
    transport : {"serial", "canopen", "modbus"}, optional
        Default: the driver's, or ``"serial"`` without a driver.
    driver_name : str, optional
        A driver name or folder (:func:`hilident.drivers.description.find_driver`);
        default: :data:`DEFAULT_DRIVERS` of the transport.

    Raises
    ------
    UsageError
        An unknown transport, or a driver of another transport than asked.
    ConfigError
        The driver cannot be found or loaded.
    """
    from hilident.drivers.description import declared_modes, find_driver, looks_like_path, valid_sample_rates

    if transport is not None and transport not in TRANSPORTS:
        raise UsageError(f"--transport {transport}: one of {', '.join(TRANSPORTS)}")
    name = driver_name or DEFAULT_DRIVERS[transport or "serial"]
    driver = find_driver(name)
    if transport is not None and driver.transport != transport:
        raise UsageError(
            f"--driver {name}: {driver.name!r} is a {driver.transport} driver, not a {transport} one "
            f"(the {transport} driver shipped: {DEFAULT_DRIVERS[transport]})"
        )
    transport = driver.transport
    rates = [r for r in valid_sample_rates(driver) if r <= 1000.0 + 1e-9] or valid_sample_rates(driver, 1)
    sample_rate = rates[0]
    try:
        modes = declared_modes(driver)
    except ConfigError:
        modes = ()
    mode = next((m for m in ("torque", "torque_injection", "velocity", "position") if m in modes), "torque")
    friction = "velocity" in modes or "position" in modes
    channels = [c.name for c in driver.channels]
    output = "velocity_mps" if "velocity_mps" in channels or not channels else channels[-1]
    # a folder given by its path is written as its absolute path: the config must find it from wherever it runs
    reference = str(driver.folder.resolve()) if looks_like_path(name) else name
    return _render(
        transport, reference, sample_rate, mode, friction, output, driver.filter_slots, no_excitation=not modes
    )


def _render(
    transport: str,
    driver: str,
    sample_rate: float,
    mode: str,
    friction: bool,
    output: str,
    filter_slots: int,
    no_excitation: bool,
) -> str:
    amplitude = _amplitude_lines(mode)
    head = [
        f"# hilident configuration: {transport} transport, driver {driver!r} (written by hilident init).",
        "# As written it runs against the driver's emulated twin: hilident run THIS_FILE",
        "# Before a real port, check every key marked CHECK (units in the comments), then try",
        "# hilident run THIS_FILE --dry-run: it connects, checks and prints the plan, and moves nothing.",
    ]
    if no_excitation:
        head.append(
            "# This driver declares no excitation mode: identify a recording of the drive (hilident identify)"
            "\n# and upload the notches with hilident upload --config THIS_FILE."
        )
    if not filter_slots:
        head.append("# This driver has no filter slots: the notches are designed and reported, not uploaded.")
    return (
        "\n".join(head)
        + f"""

[device]
{_pad(f'driver = "{driver}"')}# driver name (hilident drivers -v lists them) or a folder
port = "emulator"                # CHECK: {_PORT_NOTE[transport][0]}
                                 #        {_PORT_NOTE[transport][1]}
baudrate = 0                     # line rate in baud (CAN: bit rate, bit/s); 0: the driver's default
timeout_s = 2.0                  # s to wait for an answer from the device
host_timeout_s = 0.5             # s the device may go without hearing the host before it stops the axis itself
allow_fault_reset = false        # true: clear a latched fault at connect (or hilident run --clear-fault once)

{_TRANSPORT_TABLES[transport]}[run]
{_pad(f"sample_rate_hz = {sample_rate!r}")}# recorded rate, Hz; must divide the drive's loop rate
seed = 7                         # seed of every random excitation: the same seed gives the same run

[limits]
# CHECK all four: the session stops the axis (exit 5) when one is crossed. Start well inside the axis's
# mechanical and electrical limits; these values suit the emulated gantry.
torque_nm = 19.0                 # CHECK: largest torque command, N*m
velocity_mps = 0.4               # CHECK: largest speed, m/s
position_min_m = -0.6            # CHECK: lower end of the travel window, m (relative to where the axis starts)
position_max_m = 0.6             # CHECK: upper end of the travel window, m

[friction_test]
{_pad(f"enabled = {str(friction).lower()}")}# {_FRICTION_NOTE[friction]}
speeds_mps = [0.003, 0.006, 0.01, 0.02, 0.04, 0.08, 0.15, 0.25]   # CHECK: constant speeds, m/s, each run both ways
hold_s = 1.0                     # s at each speed (travel per leg: speed * hold_s, inside half the window)
settle_s = 0.5                   # s of each hold not averaged
accel_mps2 = 0.5                 # CHECK: acceleration between speeds, m/s^2

[excitation]
kind = "multisine"               # multisine, chirp, prbs, noise, sine, square or step
{_pad(f'mode = "{mode}"')}# where it enters: torque (open loop), torque_injection, velocity or position
{amplitude}
f_min_hz = 2.0                   # CHECK: band excited, Hz: cover the resonances you expect
f_max_hz = 80.0
period_s = 4.0                   # s per multisine period (frequency resolution 1/period_s = 0.25 Hz)
duration_s = 16.0                # s asked; a multisine plays one more period first (a lead-in, not analysed)

[identification]
{_pad(f'output = "{output}"')}# channel whose response to the excitation is measured
coherence_threshold = 0.8        # lines below it are not trusted
max_resonances = 1               # most resonances reported (and notched)

[notch]
depth_db = 40.0                  # notch depth, dB
width_factor = 2.0               # notch width over the resonance's half-power bandwidth
min_width_ratio = 0.3            # narrowest notch, as a fraction of its centre frequency
verify = true                    # run the excitation again with the notches on and measure the drop

# The emulated twin (used while port = "emulator"; ignored on a real port): the gantry of
# configs/emulated-gantry.toml. time_scale > 1 runs it faster than real time.
[emulator]
{_EMULATOR_LINK[transport]}time_scale = 4.0
seed = 3

[emulator.plant]
model = "two_mass"
m1 = 40.0                        # cart, kg
m2 = 10.0                        # load, kg
k = 1.5e5                        # beam stiffness, N/m (coupled mode near 21.8 Hz)
d = 40.0                         # beam damping, N*s/m
c = 10.0                         # torque-to-force constant, N/(N*m)

[emulator.friction]
model = "stribeck"
Fc = 0.2                         # Coulomb, N*m
Fs = 0.35                        # static, N*m
Fv = 2.0                         # viscous, N*m/(m/s)
vs = 0.005                       # Stribeck velocity, m/s

[emulator.drive]
kp_pos_per_s = 20.0
kv_nm_per_mps = 100.0
ti_s = 0.05
velocity_filter_hz = 400.0
torque_max_nm = 20.0

[emulator.sensors]
encoder_resolution_m = 1e-6
torque_noise_nm = 0.01
laser_range_m = [-0.005, 0.005]
laser_resolution_m = 1.2e-4
"""
    )


def _pad(assignment: str) -> str:
    """``assignment`` padded so that its comment starts in the column the others do."""
    return assignment + " " * max(1, 33 - len(assignment))


def _amplitude_lines(mode: str) -> str:
    if mode in ("torque", "torque_injection"):
        return (
            'amplitude_nm = "auto"            # CHECK: peak torque, N*m; "auto": chosen by short trials before '
            "the run,\n                                 #        at most limits.torque_nm (or a number, N*m)"
        )
    if mode == "velocity":
        return "amplitude_mps = 0.01             # CHECK: peak velocity set-point perturbation, m/s"
    return "amplitude_m = 0.0005             # CHECK: peak position set-point perturbation, m"


def write_starter_config(path: str | Path, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path``; an existing file is kept unless ``overwrite``.

    Raises
    ------
    UsageError
        The file exists (without ``overwrite``) or cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise UsageError(f"--out {path}: exists; pass --overwrite to replace it, or choose another name")
    if path.is_dir():
        raise UsageError(f"--out {path}: is a folder; give a file name such as {path / 'axis.toml'}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"--out {path}: cannot write there: {exc.strerror or exc}") from None
    return path
