"""``drivers check`` tries a filter slot as ``hilident run`` uses it: read, written bypassed, read back, enabled,
read back, restored.

The static checks (:mod:`hilident.drivers.filter_check`) see the objects a
``[filters]`` table names; the trial sees what a drive does with the values the
table makes: an object that refuses a value the table's scale gives (outside its
EDS LowLimit/HighLimit), a word block of another size than the drive's, an
enable that does not switch the slot, a read-back that is not what was written.
It runs the steps of :meth:`~hilident.adapters.base.AdapterBase.upload_filter`
one by one on an open device, so a failure names its step, the ``[filters]`` key
and the object, then puts back what the slot held.

The notch tried is hilident's own design (:func:`~hilident.filters.notch.design_notch`)
at a quarter of the drive's filter rate, clipped into the encoding's frequency
ranges, a fifth of its centre wide and 20 dB deep, realised in the encoding as
a session realises a designed notch.

This package imports neither the adapters nor the emulator: the command line
opens the device (a throw-away twin of the driver folder) and hands it here
(:mod:`hilident.cli.driver_trial`).
"""

from __future__ import annotations

import math
import re
from typing import Any, Protocol

import numpy as np

from hilident.drivers.filter_check import filter_key, show_address
from hilident.errors import ConfigError, HilidentError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.protocol.canopen_filters import ENABLED, FilterObjects, parse_filter_objects
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["FilterSlotDevice", "trial_filter_slot", "trial_notch"]

#: Fields that hold a frequency, Hz: the notch tried lies inside all of their ranges.
_FREQUENCY_FIELDS = ("center", "center_hz", "pole_hz", "zero_hz", "num_hz", "den_hz")
#: The notch tried: centre at this fraction of the filter rate, this fraction of the centre wide, this deep (dB).
_CENTRE_OF_RATE, _WIDTH_OF_CENTRE, _DEPTH_DB = 0.25, 0.2, 20.0
_ADDRESS = re.compile(r"0x([0-9A-Fa-f]{4})(?::(0x[0-9A-Fa-f]+|\d+))?")


class FilterSlotDevice(Protocol):
    """What the trial asks of an open device: the filter-slot methods of
    :class:`~hilident.adapters.base.AdapterBase`, its ``port`` and its ``identity`` (``loop_rate_hz``).

    On a CANopen drive :meth:`save_filter` gives the slot's raw field values and whether it runs,
    ``(dict, bool)``; the trial compares them with what it wrote.
    """

    port: str

    @property
    def identity(self) -> Any: ...

    def save_filter(self, slot: int) -> Any: ...

    def restore_filter(self, slot: int, saved: Any) -> None: ...

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None: ...

    def read_filter(self, slot: int) -> tuple[Biquad, bool]: ...

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None = None) -> Biquad: ...


def trial_notch(encoding: FilterEncoding, filter_rate_hz: float) -> NotchSpec:
    """The notch the trial writes: a quarter of ``filter_rate_hz`` clipped into the encoding's frequency ranges.

    Parameters
    ----------
    encoding : FilterEncoding
    filter_rate_hz : float
        The rate the drive runs its filters at, Hz.

    Returns
    -------
    NotchSpec
        Centre in Hz, width a fifth of the centre (Hz), depth 20 dB.

    Examples
    --------
    >>> enc = FilterEncoding.from_table({"encoding": "center_band", "ranges": {"center": [10, 2000]}})
    >>> trial_notch(enc, 16000.0).center_hz
    2000.0
    """
    low, high = 0.0, 0.45 * filter_rate_hz
    for name in _FREQUENCY_FIELDS:
        if name in encoding.ranges:
            low, high = max(low, encoding.ranges[name][0]), min(high, encoding.ranges[name][1])
    if encoding.kind == "notch_parameters" and encoding.width_unit == "hz":
        high = min(high, encoding.center_scale * encoding.max_value)
    centre = min(max(_CENTRE_OF_RATE * filter_rate_hz, low), high)
    return NotchSpec(centre, _WIDTH_OF_CENTRE * centre, _DEPTH_DB)


class _Refused(Exception):
    """A step of the trial failed; ``key`` is the ``[filters]`` key at fault, ``text`` what happened."""

    def __init__(self, key: str, text: str):
        super().__init__(text)
        self.key, self.text = key, text


def trial_filter_slot(
    device: FilterSlotDevice, table: dict, source: str, slot: int = 0, where: str = "a twin of the folder"
) -> list[str]:
    """Try filter slot ``slot`` of an open device as ``hilident run`` uploads a notch, and put its contents back.

    The slot is read; :func:`trial_notch` is written bypassed, its raw values
    read back and compared with what was written, its section compared with
    :meth:`~FilterSlotDevice.stored_form`; it is enabled and both read back
    again; the slot's previous contents are restored and read back.

    Parameters
    ----------
    device : FilterSlotDevice
        The open device (a CANopen drive or its twin).
    table : dict
        The ``[filters]`` table of its ``driver.toml``, as parsed.
    source : str
        The ``driver.toml`` path, for messages.
    slot : int
        The slot tried.
    where : str
        What the device is, for messages.

    Returns
    -------
    list of str
        One ``"<source>: [filters.<key>] ..."`` line per failure (naming the
        object where one is at fault); empty when the slot works.
    """
    try:
        encoding = FilterEncoding.from_table(table, source)
        fo = parse_filter_objects(table, source)
    except ConfigError as exc:
        return [f"{source}: [{exc.key}] {exc.message}"]
    if fo is None:
        return []
    trial = _Trial(device, table, fo, encoding, slot, where)
    saved = None
    try:
        saved = trial.step("reading", device.save_filter, slot)
        trial.run()
        trial.restore(saved)
    except _Refused as exc:
        if saved is not None:  # the first failure tells; the slot is put back as far as the device lets it
            try:
                device.restore_filter(slot, saved)
            except HilidentError:
                pass
        return [f"{source}: [{exc.key}] {exc.text}"]
    return []


class _Trial:
    def __init__(self, device, table: dict, fo: FilterObjects, encoding: FilterEncoding, slot: int, where: str):
        self.device, self.table, self.fo, self.encoding, self.slot = device, table, fo, encoding, slot
        self.where = f"filter slot {slot} ({fo.where(slot)}) on {where}"

    def run(self) -> None:
        device, slot = self.device, self.slot
        rate = float(device.identity.loop_rate_hz)
        spec = trial_notch(self.encoding, rate)
        asked = f"a {spec.center_hz:.6g} Hz notch {spec.width_hz:.4g} Hz wide, {spec.depth_db:g} dB"
        self.check_block_states()
        try:
            values = self.encoding.realise(spec, rate).fields
            biquad = design_notch(spec, rate)
        except HilidentError as exc:
            raise _Refused("filters", f"the {self.encoding.kind} encoding cannot hold {asked}: {exc}") from None
        self.step(f"writing {asked}, bypassed, to", device.write_filter, slot, biquad, spec, enabled=False)
        bypassed = self.encoding.disabled(values) if self.fo.in_block else values
        self.compare_raw(bypassed, running=not self.fo.in_block and not self.fo.has_enable)
        expected = self.step("asking the stored form of", device.stored_form, biquad, spec)
        stored, _ = self.step("reading back", device.read_filter, slot)
        self.compare_section(stored, expected, "written bypassed")
        self.step("enabling", device.write_filter, slot, biquad, spec, enabled=True)
        self.compare_raw(values, running=True)
        stored, _ = self.step("reading back", device.read_filter, slot)
        self.compare_section(stored, expected, "enabled")

    def check_block_states(self) -> None:
        """A word block's enabled state word must not read as its disabled one (the slot could never run)."""
        if not self.fo.in_block:
            return
        lay, block = self.encoding.layout, show_address(self.fo.address(self.slot, "block"))
        if lay.enabled_value & lay.state_mask == lay.disabled_value & lay.state_mask:
            raise _Refused(
                "filters.enabled_value",
                f"0x{lay.enabled_value:04X} under state_mask 0x{lay.state_mask:04X} is disabled_value "
                f"0x{lay.disabled_value:04X}: a block written enabled to {block} would read bypassed",
            )

    def restore(self, saved) -> None:
        self.step("restoring", self.device.restore_filter, self.slot, saved)
        now = self.step("reading back", self.device.save_filter, self.slot)
        if _raw_form(saved) is not None and not _same_raw(_raw_form(now), _raw_form(saved)):
            raise _Refused("filters", f"{self.where}: restored, it reads {_show_raw(now)}, not {_show_raw(saved)}")

    def step(self, what: str, call, *args, **kwargs):
        """``call(*args, **kwargs)``; a device's or encoding's error becomes a refusal naming the key and object."""
        try:
            return call(*args, **kwargs)
        except HilidentError as exc:
            text = str(exc)
            port = f"{self.device.port}: "
            text = text[len(port) :] if text.startswith(port) else text
            raise _Refused(self.key_of(text), f"{what} {self.where}: {text}") from None

    def key_of(self, text: str) -> str:
        """The ``[filters]`` key of the first filter object a device's message names (``filters`` when none)."""
        for m in _ADDRESS.finditer(text):
            owner = self.fo.owner(ObjectAddress(int(m.group(1), 16), int(m.group(2) or "0", 0)))
            if owner is not None:
                name = owner[1]
                if name == ENABLED and "enable_values" in self.table:
                    return "filters.enable_values"
                return filter_key(self.table, self.fo, name)
        return "filters"

    def compare_raw(self, written: dict, running: bool) -> None:
        """The slot's raw values and enable as read back against ``written`` (skipped when the device does not
        give them as ``(dict, bool)``)."""
        raw = _raw_form(self.step("reading back", self.device.save_filter, self.slot))
        if raw is None:
            return
        values, enabled = raw
        for name, value in written.items():
            if name in values and not _same(values[name], value):
                addr = show_address(self.fo.address(self.slot, name))
                raise _Refused(
                    filter_key(self.table, self.fo, name),
                    f"{self.where}: {addr} was written {_show(value)} and reads back {_show(values[name])}",
                )
        if bool(enabled) != running:
            raise _Refused(self._enable_key(running), f"{self.where}: {self._enable_text(running, values)}")

    def _enable_key(self, running: bool) -> str:
        if self.fo.in_block:
            return "filters.enabled_value" if running else "filters.disabled_value"
        return "filters.enable_values" if "enable_values" in self.table else filter_key(self.table, self.fo, ENABLED)

    def _enable_text(self, running: bool, values: dict) -> str:
        state = "enabled" if running else "bypassed"
        reads = "bypassed" if running else "running"
        if self.fo.in_block:
            lay, block = self.encoding.layout, bytes(values.get("block", b""))
            word = int.from_bytes(block[2 * lay.state_word : 2 * lay.state_word + 2], lay.byte_order)
            return f"the block written {state} reads {reads} (state word {lay.state_word} = 0x{word:04X})"
        addr = show_address(self.fo.address(self.slot, ENABLED))
        value = self.fo.enable_on if running else self.fo.enable_off
        return f"{addr} was written {value} ({state}) and the slot reads {reads}"

    def compare_section(self, stored: Biquad, expected: Biquad, state: str) -> None:
        if stored != expected:
            raise _Refused(
                "filters",
                f"{self.where}: the section read back {state} (b = {_coefficients(stored.b)}, "
                f"a = {_coefficients(stored.a)}) is not the one the encoding stores (b = "
                f"{_coefficients(expected.b)}, a = {_coefficients(expected.a)})",
            )


def _raw_form(saved) -> tuple[dict, bool] | None:
    """``(field values, enabled)`` when the device gives a slot's contents so, else None."""
    if isinstance(saved, tuple) and len(saved) == 2 and isinstance(saved[0], dict):
        return saved[0], bool(saved[1])
    return None


def _same(read, written) -> bool:
    """A value read back is the one written (a REAL32 as its single-precision value)."""
    if isinstance(written, float) or isinstance(read, float):
        try:
            return bool(np.float32(read) == np.float32(written)) or (math.isnan(read) and math.isnan(written))
        except (TypeError, ValueError):
            return False
    return bool(read == written)


def _same_raw(now, saved) -> bool:
    if now is None or saved is None:
        return False
    same_values = set(now[0]) == set(saved[0]) and all(_same(now[0][k], v) for k, v in saved[0].items())
    return same_values and now[1] == saved[1]


def _show(value) -> str:
    if isinstance(value, bytes | bytearray):
        return value.hex(" ", 2).upper() if value else "(empty)"
    return f"{value:.9g}" if isinstance(value, float) else repr(value)


def _show_raw(saved) -> str:
    raw = _raw_form(saved)
    if raw is None:
        return repr(saved)
    return ", ".join(f"{k} = {_show(v)}" for k, v in raw[0].items()) + (" (running)" if raw[1] else " (bypassed)")


def _coefficients(values) -> str:
    return "(" + ", ".join(f"{v:.9g}" for v in values) + ")"
