"""The PDO layout of a host-streamed CANopen run, planned from the driver description and the EDS, and checked.

:func:`plan_streamed_run` computes what a streamed run maps: the channels packed
into the TPDOs the EDS declares (each headed by the sample counter on a drive
with the hilident counters), the set-point (headed by the set-point counter)
in the first RPDO, and the PDOs it empties. The adapter writes exactly this
plan, and ``hilident drivers check`` and ``hilident run`` check it before
anything moves, so what the check accepts is what the run maps.

Every object the plan maps or writes is checked against the EDS as CiA 301
has a drive check it: a mapped object must be PDO-mappable, numeric, readable
(TPDO) or writable (RPDO); a PDO carries at most 64 bits and no more entries
than its mapping record has sub-indices (and its sub-index 0 accepts); the
communication and mapping parameters must be writable, and the COB-IDs and
transmission type the host writes must be within the range the EDS gives.
A refusal names the object (index:sub and its EDS name) and what to change.

:func:`capture_problems` and :func:`recorder_problems` check what the
drive-buffered and the recorder acquisitions map.

All pure: an object dictionary (canopen's, as loaded from the EDS) and the
description in, dataclasses and messages out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from hilident.errors import ConfigError, DataError
from hilident.protocol.canopen_objects import CanopenDescription, mapping_entry, pack_frames, type_bits
from hilident.protocol.canopen_profile import mapping_capacity
from hilident.protocol.canopen_types import ObjectAddress

__all__ = [
    "SYNCHRONOUS",
    "EVENT_DRIVEN",
    "BUFFER_ROLES",
    "buffers_setpoints",
    "PdoSlot",
    "PlannedPdo",
    "PdoPlan",
    "RunChannel",
    "pdo_slots",
    "plan_streamed_run",
    "pdo_plan_problems",
    "capture_problems",
    "recorder_problems",
]

#: Transmission type the host writes into every PDO it maps: synchronous, every SYNC (CiA 301).
SYNCHRONOUS = 1
#: Transmission type of an RPDO whose data go into a drive's buffer as they come (event-driven, CiA 301): the
#: interpolation data of a drive with an interpolation data buffer (0x60C4), which takes one record per SYNC.
EVENT_DRIVEN = 255
#: The roles that say a drive buffers its interpolation data (CiA 402 0x60C4).
BUFFER_ROLES = ("ip_buffer_max", "ip_buffer_size", "ip_buffer_clear")


def buffers_setpoints(desc, setpoint: str) -> bool:
    """The run's set-points (``setpoint``: their role) are interpolation data and the drive describes a buffer
    for them (:data:`BUFFER_ROLES`)."""
    return setpoint == "interpolation_data" and all(desc.has(r) for r in BUFFER_ROLES)


#: (communication base, mapping base, predefined COB-ID base) of each kind of PDO.
_BASES = {"rpdo": (0x1400, 0x1600, 0x200), "tpdo": (0x1800, 0x1A00, 0x180)}
#: RPDOs a streamed run empties beside the one carrying the set-point (2-4: the predefined connection set).
_EMPTIED_RPDOS = 3


@dataclass(frozen=True)
class PdoSlot:
    """One PDO the drive's EDS declares: its number (0 for PDO 1), how many objects it maps at most, its COB-ID."""

    number: int
    max_entries: int
    cob_id: int


@dataclass(frozen=True)
class RunChannel:
    """A recorded channel as the plan sees it: its name and the object carrying it (None: the host records it)."""

    name: str
    address: ObjectAddress | None


@dataclass(frozen=True)
class PlannedPdo:
    """One PDO as a streamed run writes it.

    Attributes
    ----------
    kind : {"tpdo", "rpdo"}
    slot : PdoSlot
    entries : tuple of (ObjectAddress, int)
        The mapped objects and their widths in bits, the counter first on a counted drive; empty: the PDO is
        emptied and left invalid.
    columns : tuple of int
        The channel columns a TPDO carries, in the order of its entries after the counter.
    transmission : int
        The transmission type written (:data:`SYNCHRONOUS`, or :data:`EVENT_DRIVEN` for buffered set-points).
    """

    kind: str
    slot: PdoSlot
    entries: tuple[tuple[ObjectAddress, int], ...] = ()
    columns: tuple[int, ...] = ()
    transmission: int = SYNCHRONOUS

    @property
    def comm_index(self) -> int:
        """The index of the communication parameter (0x1400 + n, 0x1800 + n)."""
        return _BASES[self.kind][0] + self.slot.number

    @property
    def map_index(self) -> int:
        """The index of the mapping parameter (0x1600 + n, 0x1A00 + n)."""
        return _BASES[self.kind][1] + self.slot.number

    @property
    def mapping_entries(self) -> list[int]:
        """The CiA 301 mapping entries written into sub-indices 1..n of the mapping parameter."""
        return [mapping_entry(address, bits) for address, bits in self.entries]

    @property
    def name(self) -> str:
        return f"{self.kind.upper()} {self.slot.number + 1}"


@dataclass(frozen=True)
class PdoPlan:
    """What a streamed run maps, in the order the adapter writes it.

    Attributes
    ----------
    tpdos : tuple of PlannedPdo
        Every TPDO the EDS declares, in number order; those that carry no channel are emptied.
    rpdos : tuple of PlannedPdo
        The RPDO carrying the set-point, then the RPDOs it empties (2-4).
    """

    tpdos: tuple[PlannedPdo, ...]
    rpdos: tuple[PlannedPdo, ...]

    @property
    def carrying(self) -> tuple[PlannedPdo, ...]:
        """The TPDOs that carry channels."""
        return tuple(p for p in self.tpdos if p.entries)

    @property
    def setpoint_pdo(self) -> PlannedPdo:
        return self.rpdos[0]


def describe(od, address: ObjectAddress) -> str:
    """``0x1A00:0 (TPDO mapping parameter 1: Number of mapped objects)``: an object as messages name it."""
    var = od.get_variable(address.index, address.subindex)
    if var is None:
        return f"{address} (not in the EDS)"
    parent = getattr(var, "parent", None)
    record = getattr(parent, "name", None) if parent is not None and hasattr(parent, "subindices") else None
    return f"{address} ({record}: {var.name})" if record else f"{address} ({var.name})"


def pdo_slots(od, kind: str, node_id: int) -> list[PdoSlot]:
    """The RPDOs (``kind = "rpdo"``) or TPDOs the EDS declares, with their mapping capacity.

    A PDO counts when both its communication and its mapping object exist and it maps at least one object;
    its capacity is :func:`~hilident.protocol.canopen_profile.mapping_capacity`. The COB-ID is the predefined
    connection set's for PDOs 1-4 (``node_id`` added) and the EDS default for the others.
    """
    comm_base, map_base, cob_base = _BASES[kind]
    slots = []
    for n in range(512):
        if comm_base + n not in od or map_base + n not in od:
            continue
        capacity = mapping_capacity(od[map_base + n])
        if n < 4:
            cob = cob_base + 0x100 * n + node_id
        else:
            var = od.get_variable(comm_base + n, 1)
            cob = int(var.default or 0) & 0x7FF if var is not None else 0
        if capacity and cob:
            slots.append(PdoSlot(n, capacity, cob))
    return slots


# --- the plan ---------------------------------------------------------------------------------------------------


def plan_streamed_run(
    od, desc: CanopenDescription, node_id: int, channels: Sequence[RunChannel], setpoint: str
) -> PdoPlan:
    """The PDO layout of a streamed run, checked against the EDS.

    Parameters
    ----------
    od : canopen.ObjectDictionary
        The drive's EDS.
    desc : CanopenDescription
        The drive's objects by role (the counters, the set-point), its EDS file name.
    node_id : int
        The drive's node id (the COB-IDs of PDOs 1-4).
    channels : sequence of RunChannel
        The recorded channels in column order; those the host records are not mapped.
    setpoint : str
        The role of the mode's set-point object (``"target_torque"``, ...).

    Returns
    -------
    PdoPlan

    Raises
    ------
    ConfigError
        Naming ``desc.eds``, every object the run cannot map or write (index:sub and EDS name) and what to
        change.
    """
    problems = _object_problems(od, desc, channels, setpoint)
    if problems:
        raise _refusal(desc, problems)
    plan = PdoPlan(_plan_tpdos(od, desc, node_id, channels), _plan_rpdos(od, desc, node_id, setpoint))
    problems = pdo_plan_problems(od, plan)
    if problems:
        raise _refusal(desc, problems)
    return plan


def _refusal(desc: CanopenDescription, problems: Sequence[str]) -> ConfigError:
    return ConfigError("canopen", "; ".join(problems), desc.eds)


def _header(od, desc: CanopenDescription, role: str) -> list[tuple[ObjectAddress, int]]:
    """The counter heading each PDO on a counted drive (``role``: its object), else nothing."""
    if not desc.counted:
        return []
    address = desc.address(role)
    return [(address, _bits(od, address))]


def _bits(od, address: ObjectAddress) -> int:
    return type_bits(od.get_variable(address.index, address.subindex).data_type)


def _plan_tpdos(od, desc: CanopenDescription, node_id: int, channels: Sequence[RunChannel]) -> tuple[PlannedPdo, ...]:
    """The channels packed first-fit into the TPDOs (at most the smallest capacity of TPDOs 1-4 each)."""
    slots = pdo_slots(od, "tpdo", node_id)
    header = _header(od, desc, "sample_counter")
    mapped = [(i, c) for i, c in enumerate(channels) if c.address is not None]
    per_frame = min((s.max_entries for s in slots[:4]), default=0) - len(header)
    try:
        frames = pack_frames(
            [(c.name, _bits(od, c.address)) for _, c in mapped if c.address is not None],
            header_bits=sum(bits for _, bits in header),
            max_frames=len(slots),
            max_entries=per_frame,
        )
    except DataError as exc:
        raise ConfigError(
            "run.channels",
            f"{exc} (the EDS declares {len(slots)} TPDOs of "
            f"{', '.join(str(s.max_entries) for s in slots) or 'no'} entries): map fewer channels",
            desc.eds,
        ) from None
    column_of = {c.name: i for i, c in mapped}
    planned = []
    for i, slot in enumerate(slots):
        members = frames[i] if i < len(frames) else []
        columns = tuple(column_of[name] for name in members)
        entries = header + [(_address(channels[j]), _bits(od, _address(channels[j]))) for j in columns]
        planned.append(PlannedPdo("tpdo", slot, tuple(entries) if members else (), columns))
    return tuple(planned)


def _address(channel: RunChannel) -> ObjectAddress:
    assert channel.address is not None  # only channels a drive object carries are packed
    return channel.address


def _plan_rpdos(od, desc: CanopenDescription, node_id: int, setpoint: str) -> tuple[PlannedPdo, ...]:
    """The set-point (headed by the set-point counter) in the first RPDO; RPDOs 2-4 emptied."""
    slots = pdo_slots(od, "rpdo", node_id)
    if not slots:
        raise ConfigError(
            "canopen", "the EDS declares no RPDO: set-points cannot be streamed (choose another acquisition)", desc.eds
        )
    address = desc.address(setpoint)
    entries = _header(od, desc, "setpoint_counter") + [(address, _bits(od, address))]
    transmission = EVENT_DRIVEN if buffers_setpoints(desc, setpoint) else SYNCHRONOUS
    first = PlannedPdo("rpdo", slots[0], tuple(entries), transmission=transmission)
    return (first,) + tuple(PlannedPdo("rpdo", slot) for slot in slots[1 : 1 + _EMPTIED_RPDOS])


# --- the checks -------------------------------------------------------------------------------------------------


def _object_problems(od, desc: CanopenDescription, channels: Sequence[RunChannel], setpoint: str) -> list[str]:
    """Every object the run maps that cannot be mapped: not in the EDS, not PDO-mappable, not numeric, or
    without the access its direction needs."""
    tx = [(f"channel {c.name!r}", c.address) for c in channels if c.address is not None]
    rx = [(f"the set-point ({setpoint})", desc.address(setpoint))]
    if desc.counted:
        tx.insert(0, ("the sample counter", desc.address("sample_counter")))
        rx.insert(0, ("the set-point counter", desc.address("setpoint_counter")))
    problems = [p for what, a in tx if (p := _mappable_problem(od, a, what, "tpdo"))]
    return problems + [p for what, a in rx if (p := _mappable_problem(od, a, what, "rpdo"))]


def _mappable_problem(od, address: ObjectAddress, what: str, kind: str) -> str:
    """Why ``address`` cannot be mapped into a PDO of ``kind`` ("" when it can)."""
    var = od.get_variable(address.index, address.subindex)
    name = describe(od, address)
    if var is None:
        return f"{name}, which carries {what}, is not in the EDS"
    if not var.pdo_mappable:
        return f"{name}, which carries {what}, is not PDO-mappable in the EDS (PDOMapping=0): " + (
            "leave the channel out of run.channels (read it by SDO) or name another object in [canopen.channels]"
            if kind == "tpdo"
            else "choose a mode whose set-point object is mappable"
        )
    try:
        type_bits(var.data_type or 0)
    except DataError:
        return f"{name}, which carries {what}, has data type 0x{var.data_type or 0:04X}: a PDO maps numeric objects"
    needed = "readable" if kind == "tpdo" else "writable"
    if not (var.readable if kind == "tpdo" else var.writable):
        return f"{name}, which carries {what}, is {var.access_type!r} in the EDS; a {kind.upper()} needs it {needed}"
    return ""


def pdo_plan_problems(od, plan: PdoPlan) -> list[str]:
    """What a drive following CiA 301 would refuse of ``plan``, one message per object (empty: nothing).

    Checks, for every PDO the plan writes: its entries against its mapping record (at most 64 bits, no more
    entries than the record's sub-indices and sub-index 0's range), the writability of the mapping and
    communication parameters it writes, and the COB-IDs and transmission type against the EDS's ranges.
    """
    problems: list[str] = []
    for pdo in plan.tpdos + plan.rpdos:
        problems += _size_problems(od, pdo)
        problems += _parameter_problems(od, pdo)
    return problems


def _size_problems(od, pdo: PlannedPdo) -> list[str]:
    """More than 64 bits, or more entries than the mapping record takes."""
    problems = []
    bits = sum(b for _, b in pdo.entries)
    head = describe(od, ObjectAddress(pdo.map_index, 0))
    if bits > 64:
        problems.append(f"{pdo.name} would carry {bits} bits, more than 64: map fewer channels")
    capacity = mapping_capacity(od[pdo.map_index])
    if len(pdo.entries) > capacity:
        problems.append(
            f"{head} takes at most {capacity} entries; {pdo.name} would map {len(pdo.entries)}: "
            "map fewer channels or choose another TPDO"
        )
    return problems


def _parameter_problems(od, pdo: PlannedPdo) -> list[str]:
    """The parameters the host writes: present, writable, and the values within the EDS's range."""
    cob = pdo.slot.cob_id
    # the invalid COB-ID (bit 31 set) is written as it is: many EDS files give the range of the valid ones only
    writes = [(ObjectAddress(pdo.comm_index, 1), None), (ObjectAddress(pdo.map_index, 0), 0)]
    if pdo.entries:
        writes += [(ObjectAddress(pdo.map_index, i), e) for i, e in enumerate(pdo.mapping_entries, start=1)]
        writes += [(ObjectAddress(pdo.map_index, 0), len(pdo.entries))]
        writes += [(ObjectAddress(pdo.comm_index, 2), pdo.transmission), (ObjectAddress(pdo.comm_index, 1), cob)]
    return [p for address, value in writes if (p := _write_problem(od, address, value, pdo))]


def _write_problem(od, address: ObjectAddress, value: int | None, pdo: PlannedPdo) -> str:
    """Why the host cannot write ``value`` (None: any value) to ``address`` ("" when it can)."""
    var = od.get_variable(address.index, address.subindex)
    name = describe(od, address)
    if var is None:
        return f"{name} is not in the EDS; {pdo.name} cannot be configured: choose another {pdo.kind.upper()}"
    if not var.writable:
        return (
            f"{name} is {var.access_type!r} in the EDS; the host writes it to configure {pdo.name}: "
            f"the drive's {pdo.kind.upper()} mapping is fixed, choose another acquisition"
        )
    low, high = var.min, var.max
    if value is not None and ((low is not None and value < low) or (high is not None and value > high)):
        what = "transmission type" if address.subindex == 2 and address.index == pdo.comm_index else "value"
        return (
            f"{name} takes {low if low is not None else '...'}..{high if high is not None else '...'} in the EDS; "
            f"{pdo.name} needs the {what} 0x{value:X}"
            + (": the drive does not send it on every SYNC, choose another TPDO" if what == "transmission type" else "")
        )
    return ""


def capture_problems(od, desc: CanopenDescription, channels: Sequence[RunChannel]) -> list[str]:
    """What a drive-buffered run's capture mapping (``capture_mapping``) cannot take of ``channels``."""
    if not desc.has("capture_mapping"):
        return ["the driver names no capture_mapping object ([canopen.objects]): a buffered run cannot record"]
    index = desc.address("capture_mapping").index
    record = od[index] if index in od else None
    capacity = mapping_capacity(record) if record is not None else 0
    problems = []
    mapped = [c for c in channels if c.address is not None]
    if len(mapped) > capacity:
        problems.append(
            f"{describe(od, ObjectAddress(index, 0))} takes {capacity} entries; a buffered run records "
            f"{len(mapped)} channels: record fewer channels (run.channels)"
        )
    for channel in mapped:
        var = od.get_variable(channel.address.index, channel.address.subindex) if channel.address else None
        if var is None or not var.readable:
            problems.append(f"channel {channel.name!r}: {describe(od, _address(channel))} cannot be read")
    return problems


def recorder_problems(desc: CanopenDescription, channels: Sequence[RunChannel]) -> list[str]:
    """What the drive's recorder cannot take of ``channels`` (its channel-selection objects)."""
    if desc.recorder is None:
        return ['acquisition "recorder": the driver describes no [canopen.recorder]']
    wanted = len([c for c in channels if c.address is not None])
    generator = desc.recorder.generator
    if any(c.address is None for c in channels) and generator is not None and generator.output is not None:
        wanted += 1  # the generator's output object records the excitation
    slots = len(desc.recorder.recorder.channels)
    if wanted > slots:
        return [f"{wanted} recorded channels; the drive's recorder has {slots} ([canopen.recorder] channels)"]
    return []
