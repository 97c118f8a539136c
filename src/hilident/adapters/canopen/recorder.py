"""Recorder runs on a CANopen drive: the drive's own generator plays, its own recorder records.

For drives that cannot play an arbitrary table but have a vendor generator
and recorder, described by ``[canopen.generator]`` and ``[canopen.recorder]``
(:mod:`hilident.protocol.canopen_recorder`; ``device.acquisition =
"recorder"``):

1. The excitation *recipe* (``adapter.set_excitation_recipe``) is mapped onto
   the generator's parameters; a recipe it cannot play (a kind it lacks, an
   amplitude or frequency out of its range, more samples than the recorder
   holds) is a ConfigError before anything is written.
2. The recorder's channel-selection objects get the mapping entries of the
   channels asked for (and of the generator's output object when the drive has
   one: that is the recorded ``excitation``; otherwise the excitation is
   computed from the parameters the drive stores, and an event says so); its
   sample period, sample count and trigger (the generator's start) follow, the
   generator's kind, target and parameters are written and read back.
3. The recorder is started (it waits for its trigger), the drive enabled in the
   mode's mode of operation, the generator started. While they run, the host
   watches the heartbeat and the emergencies, and polls the recorder's state.
4. The buffer(s) are read by SDO (block transfer when ``[canopen.recorder]
   block_transfer``), decoded and delivered from sample 0. A recorder that
   ends with fewer samples than asked has them delivered and the rest counted
   lost (never filled), then the run ends with DeviceError naming the object;
   so does a buffer shorter than the count it reported.

The generator and the recorder are stopped on every ending, and the adapter's
``stream()`` leaves the drive in Switch On Disabled.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence

import numpy as np

from hilident.adapters.base import RunResult, RunStrategy
from hilident.adapters.canopen.common import ChannelCodec
from hilident.adapters.canopen.streamed import Deliver, DriveHost
from hilident.drivers.description import DriverDescription
from hilident.errors import ConfigError, DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol.canopen_objects import (
    CanopenDescription,
    mapping_entry,
    numpy_type,
    record_dtype,
)
from hilident.protocol.canopen_pdo_plan import RunChannel, recorder_problems
from hilident.protocol.canopen_recorder import (
    GeneratorSettings,
    GeneratorSpec,
    RecorderCapability,
    generator_output,
    plan_generator,
)
from hilident.protocol.canopen_types import ObjectAddress

__all__ = ["RecorderRun", "check_recorder_channels"]

_POLL_S = 0.05
_POSITION_SETPOINTS = ("target_position", "interpolation_data")


def _capability(desc: CanopenDescription, driver: DriverDescription) -> RecorderCapability:
    """The drive's recorder (and generator); ConfigError naming the driver file when it describes none."""
    if desc.recorder is None:
        raise ConfigError(
            "device.acquisition",
            f'"recorder": driver {driver.name!r} describes no [canopen.recorder]',
            str(driver.folder / "driver.toml"),
        )
    return desc.recorder


def check_recorder_channels(
    desc: CanopenDescription, driver: DriverDescription, codecs: Sequence[ChannelCodec]
) -> None:
    """ConfigError (naming the driver file) unless the drive has a recorder that takes the channels of ``codecs``
    (the count :func:`~hilident.protocol.canopen_pdo_plan.recorder_problems` makes for ``drivers check`` too)."""
    _capability(desc, driver)
    problems = recorder_problems(desc, [RunChannel(c.name, c.address) for c in codecs])
    if problems:
        raise ConfigError("run.channels", problems[0], str(driver.folder / "driver.toml"))


class RecorderRun(RunStrategy):
    """One run of the drive's generator and recorder (see the module docstring).

    The strategy of ``"recorder"`` acquisition (the adapter's ``ACQUISITIONS``
    table). State: the generator's settings for the run, the objects the
    recorder records. The recipe is the adapter's ``excitation_recipe``
    (``set_excitation_recipe``).
    """

    ad: DriveHost

    def __init__(self, adapter: DriveHost, x: np.ndarray, deliver: Deliver, result: RunResult):
        super().__init__(adapter, x, deliver, result)
        ad = adapter
        self.cap = _capability(ad.desc, ad.driver)
        self.rec = self.cap.recorder
        self.source = str(ad.driver.folder / "driver.toml")
        if ad.excitation_recipe is None:
            raise ConfigError(
                "device.acquisition",
                '"recorder" plays only what the drive\'s generator plays, '
                "and this run has no excitation recipe (the friction test's "
                "ramps are host-streamed: set friction_test.enabled = false, or "
                'run the friction test with device.acquisition = "streamed")',
                self.source,
            )
        self.recipe: dict = ad.excitation_recipe
        self.period = ad.layout.divider
        self.settings: GeneratorSettings | None = None  # what plan() chose
        self.channels: list[tuple[ObjectAddress, int, float]] = []  # (object, data type, SI per unit) recorded
        self.excitation_column: int | None = None  # index into self.channels, or None: computed

    # --- planning (nothing moves) ----------------------------------------------------------------

    def plan(self, n: int) -> GeneratorSettings:
        """The generator's settings for ``n`` samples; ConfigError when the drive cannot play the recipe."""
        ad = self.ad
        if self.period not in self.rec.sample_periods:
            raise ConfigError(
                "run.sample_rate_hz",
                f"{ad.layout.sample_rate_hz:g} Hz is a sample period of {self.period} "
                f"loop cycles; the drive's recorder takes "
                f"{list(self.rec.sample_periods)} ([canopen.recorder] "
                "sample_periods)",
                self.source,
            )
        target = ad.desc.modes[ad.layout.mode].setpoint
        scales: dict[str, float] = {}
        for kind, role in (
            ("torque", "target_torque"),
            ("velocity", "target_velocity"),
            ("position", "target_position"),
        ):
            with contextlib.suppress(Exception):
                scales[kind] = ad.desc.scale(role, ad.ratings.torque_nm, ad.ratings.current_a)
        try:
            self.settings = plan_generator(
                self.cap, self.recipe, target, n, self.period, ad.drive_identity().loop_rate_hz, scales
            )
        except KeyError as exc:  # a parameter scaled like torque on a drive whose torque cannot be scaled
            raise DeviceError(
                f"{ad.port}: the generator's {exc.args[0]} parameters cannot be scaled: {ad.ratings.torque_problem}"
            ) from None
        return self.settings

    def planned(self) -> GeneratorSettings:
        """The settings :meth:`plan` chose (RuntimeError before it ran: a misuse of this class)."""
        if self.settings is None:
            raise RuntimeError("RecorderRun.plan() has not run: the generator's settings are not known yet")
        return self.settings

    def generator(self) -> GeneratorSpec:
        """The drive's generator; ConfigError when the driver describes none (:meth:`plan` refuses that first)."""
        if self.cap.generator is None:
            raise ConfigError(
                "device.acquisition",
                '"recorder" plays what the drive\'s generator plays, and the driver describes no [canopen.generator]',
                self.source,
            )
        return self.cap.generator

    def expected(self, n: int) -> np.ndarray:
        """What the generator plays at the recorder's ``n`` sample instants, from the values it stores."""
        s = self.planned()
        return generator_output(s.kind, s.values, np.arange(n) * self.period, self.ad.drive_identity().loop_rate_hz)

    # --- the run -------------------------------------------------------------------------------------

    def run(self) -> None:
        """Set up, play, record, upload; a fault ends it early (the adapter raises it once the axis is safe)."""
        ad, n, x = self.ad, self.n, self.x
        settings = self.plan(n)
        gen = self.generator()
        self._compare(x, n, settings)
        try:
            self._set_up(n, settings, gen)
            ad.sdo.write_object(self.rec.control, self.rec.commands["start"])  # waits for the generator's start
            self._hold_axis()
            ad.enable()
            ad.sdo.write_object(gen.control, gen.commands["start"])
            recorded = min(n, self._wait(n))  # a recorder that kept going past n: the n asked for
        finally:
            self._stop()
        if ad.run_fault is not None:  # what was recorded up to the fault; the fault ends the run
            with contextlib.suppress(DeviceError):
                self._upload(min(n, int(ad.sdo.read_object(self.rec.recorded))))
            return
        self._upload(recorded)
        self.finish_capture(
            recorded,
            f"the drive's recorder holds only {recorded} of {n} samples "
            f"({ad.sdo.describe(self.rec.recorded)}): its recording ended early",
            f"the drive's {settings.kind.name} generator played and its recorder took {n} samples",
        )

    def _compare(self, x: np.ndarray, n: int, settings: GeneratorSettings) -> None:
        """A warning event when the generator will not play what the host meant (its samples ``x``)."""
        kind = settings.kind
        if kind.name == "prbs" and not kind.taps:
            self.ad.log_event(
                RunEvent(
                    Kind.EXCITATION_DIFFERS,
                    "the drive's PRBS sequence is not described "
                    "([canopen.generator.kinds.prbs] taps): what it plays cannot be compared",
                    0,
                    value=float("nan"),
                )
            )
            return
        expected = self.expected(n)
        step = abs(settings.values["amplitude"] - float(self.recipe.get("amplitude", 0.0)))
        diff = np.abs(expected - x)
        worst = int(np.argmax(diff)) if n else 0
        if n and diff[worst] > step + 1e-6 * max(1.0, abs(settings.values["amplitude"])):
            self.ad.log_event(
                RunEvent(
                    Kind.EXCITATION_DIFFERS,
                    f"the drive's {kind.name} generator plays another signal than the host's "
                    f"excitation (largest difference {diff[worst]:.4g} at sample {worst}); the recording holds "
                    "what the drive played",
                    worst,
                    value=float(diff[worst]),
                )
            )

    def _set_up(self, n: int, settings: GeneratorSettings, gen: GeneratorSpec) -> None:
        """Recorder channels, period, count and trigger; the generator's kind, target and parameters (read back)."""
        ad, rec = self.ad, self.rec
        ad.sdo.write_object(rec.control, rec.commands["stop"])
        ad.sdo.write_object(gen.control, gen.commands["stop"])
        objects: list[tuple[ObjectAddress, int, float]] = []
        self.excitation_column = None
        for c in ad.layout.channels:
            if c.address is not None:  # a drive object (else the host's own column: the excitation)
                objects.append((c.address, c.datatype, c.scale))
            elif gen.output is not None:
                self.excitation_column = len(objects)
                scale = (
                    gen.output_scale
                    if not isinstance(gen.output_scale, str)
                    else ad.scale(
                        {"torque": "target_torque", "velocity": "target_velocity", "position": "target_position"}[
                            gen.output_scale
                        ]
                    )
                )
                objects.append((gen.output, ad.sdo.data_type(gen.output), scale))
        self.channels = objects
        for i, addr in enumerate(rec.channels):
            entry = mapping_entry(objects[i][0], numpy_type(objects[i][1]).itemsize * 8) if i < len(objects) else 0
            ad.sdo.write_object(addr, entry)
        ad.sdo.write_object(rec.sample_period, self.period)
        ad.sdo.write_object(rec.samples, n)
        ad.sdo.write_object(rec.trigger, rec.triggers["generator"])
        s = settings
        if gen.kind is not None:
            ad.sdo.write_object(gen.kind, s.kind.code)
        ad.sdo.write_object(gen.target, gen.targets[s.target])
        for name, raw in s.raw.items():
            addr = s.kind.parameters[name].address
            ad.sdo.write_object(addr, raw)
            back = int(ad.sdo.read_object(addr))
            if back != raw:
                raise DeviceError(
                    f"{ad.port}: wrote {raw} to {ad.sdo.describe(addr)} (generator {name}), the drive holds {back}"
                )
        if any(c.on_host for c in ad.layout.channels) and self.excitation_column is None:
            ad.log_event(
                RunEvent(
                    Kind.EXCITATION_COMPUTED,
                    f"the drive has no generator output object: the "
                    f"excitation column is its {s.kind.name} computed "
                    "from the parameters it stores",
                    0,
                    value=0.0,
                )
            )

    def _hold_axis(self) -> None:
        """A harmless set-point before enabling: zero torque/speed, the present position in CSP/IP."""
        ad = self.ad
        spec = ad.desc.modes[ad.layout.mode]
        for role in (spec.setpoint, spec.hold):
            if role:
                ad.sdo.write(role, int(ad.sdo.read("position_actual")) if role in _POSITION_SETPOINTS else 0)

    def _wait(self, n: int) -> int:
        """Poll the recorder until it is done; emergencies and the heartbeat watched. Returns its count."""
        ad, rec = self.ad, self.rec
        recorded = 0
        last_change = time.monotonic()
        stall_limit = max(2.0, 2 * ad.timeout_s)
        while True:
            if self.ad.take_emergency_fault(recorded) is not None:
                return recorded
            ad.net.check_link()
            state = int(ad.sdo.read_object(rec.state))
            count = int(ad.sdo.read_object(rec.recorded))
            if count != recorded:
                recorded, last_change = count, time.monotonic()
            if state == rec.states["done"] or state == rec.states["idle"]:
                return recorded
            if time.monotonic() - last_change > stall_limit:
                raise DeviceError(
                    f"{ad.port}: the recorder stalled at {recorded} of {n} samples for "
                    f"{stall_limit:g} s ({ad.sdo.describe(rec.recorded)})"
                )
            time.sleep(_POLL_S)

    def _stop(self) -> None:
        """Generator off, recorder off, power stage off: on every ending, whatever fails."""
        ad = self.ad
        gen = self.cap.generator
        if gen is not None:
            with contextlib.suppress(Exception):
                ad.sdo.write_object(gen.control, gen.commands["stop"])
        ad.safe_stop()
        with contextlib.suppress(Exception):
            if int(ad.sdo.read_object(self.rec.state)) != self.rec.states["done"]:
                ad.sdo.write_object(self.rec.control, self.rec.commands["stop"])

    def _upload(self, recorded: int) -> None:
        """Read the buffer(s), decode, deliver samples 0 .. recorded-1."""
        ad, rec = self.ad, self.rec
        if recorded == 0:
            return
        types = [t for _, t, _ in self.channels]
        if rec.interleaved:
            dtype = record_dtype(types)
            data = self._read(rec.buffers[0])
            if len(data) < recorded * dtype.itemsize:
                raise DeviceError(
                    f"{ad.port}: the recorder's buffer {ad.sdo.describe(rec.buffers[0])} holds "
                    f"{len(data)} bytes; {recorded} samples of {dtype.itemsize} bytes were recorded"
                )
            records = np.frombuffer(data[: recorded * dtype.itemsize], dtype=dtype)
            columns = [records[f"f{i}"] for i in range(len(types))]
        else:
            columns = []
            for i, t in enumerate(types):
                size = numpy_type(t).itemsize
                data = self._read(rec.buffers[i])
                if len(data) < recorded * size:
                    raise DeviceError(
                        f"{ad.port}: the recorder's buffer {ad.sdo.describe(rec.buffers[i])} holds "
                        f"{len(data) // size} samples; {recorded} were recorded"
                    )
                columns.append(np.frombuffer(data[: recorded * size], dtype=numpy_type(t)))
        si = [col.astype(float) * scale for col, (_, _, scale) in zip(columns, self.channels, strict=False)]
        rows, k = [], 0
        for c in ad.layout.channels:
            if c.on_host and self.excitation_column is None:
                rows.append(self.expected(recorded))
            else:
                rows.append(si[k])
                k += 1
        self.stats.samples += recorded
        self.deliver(np.arange(recorded, dtype=np.int64), np.column_stack(rows))

    def _read(self, addr: ObjectAddress) -> bytes:
        """A recorder buffer, by block transfer when ``[canopen.recorder] block_transfer`` says so."""
        return self.ad.sdo.read_domain(addr, block_transfer=self.rec.block_transfer)
