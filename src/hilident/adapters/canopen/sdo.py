"""Object access by SDO for the CANopen adapter: read and write by role or address, block transfers, aborts named.

:class:`SdoAccess` is a part :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` owns (its
``sdo``); the other parts and the acquisition strategies reach the drive's objects through it.
"""

from __future__ import annotations

import contextlib
import io
import queue
import time
from collections.abc import Callable
from struct import error as struct_error
from typing import TypeVar

import can
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from canopen.sdo.client import BlockDownloadStream, BlockUploadStream

import canopen
from hilident.adapters.canopen.common import (
    _ABORT_GENERAL,
    ObjectValue,
    _transfer_error,
)
from hilident.endings import raise_pending, shielded, uninterruptible
from hilident.errors import DataError, DeviceError
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_types import ObjectAddress

_Stream = TypeVar("_Stream", bound=io.RawIOBase)  # the block transfer stream a body reads or writes
_Result = TypeVar("_Result")  # what the body returns

STALE_QUIET_S = 0.05
"""An SDO channel is clear of stale answers once no frame has come for this long (s)."""
STALE_DRAIN_LIMIT_S = 1.0
"""The longest a drain of stale answers waits (s): a server that keeps talking is not waited out."""


def _out_of_step(exc: SdoCommunicationError) -> bool:
    """Whether canopen rejected an answer as not the one to its request (a stale frame), not a silence."""
    text = str(exc)
    return text.startswith("Unexpected response") or "instead, maybe there is another SDO client" in text


def drain_stale_answers(client: canopen.sdo.SdoClient) -> int:
    """Take every late frame off an SDO client's response queue until the channel is quiet.

    An aborted block upload leaves sub-block segments in flight, and an answer
    canopen rejected as out of step is followed by the answer it was waiting
    for: either, read as the answer to the next request, makes that request
    fail (``Unexpected response 0x60``) and leaves the channel one answer behind.

    Returns
    -------
    int
        How many stale frames were taken off.
    """
    taken = 0
    deadline = time.monotonic() + STALE_DRAIN_LIMIT_S
    while time.monotonic() < deadline:
        try:
            client.responses.get(timeout=STALE_QUIET_S)
        except queue.Empty:
            break
        taken += 1
    return taken


class SdoAccess:
    """Every SDO read and write of the CANopen adapter, so an abort or a lost bus becomes a
    :class:`~hilident.errors.DeviceError` that names the object and the abort's meaning.

    Parameters
    ----------
    node : canopen.RemoteNode
        The drive, with its EDS as object dictionary.
    desc : CanopenDescription
        The drive's objects by role (for :meth:`read` and :meth:`write`), its EDS file name (for messages)
        and whether DOMAIN objects go by block transfer.
    port : str
        Where the drive is (interface, channel, node id); used in messages.
    beat : callable
        Called before every request: the host's heartbeat when it is due
        (:meth:`~hilident.adapters.canopen.net.HostHeartbeat.beat_if_due`).

    Attributes
    ----------
    block_transfer : bool
        DOMAIN objects go by SDO block transfer unless a call says otherwise (the description's
        ``block_transfer``).
    in_block_transfer : bool
        A block transfer is under way (:meth:`abort_interrupted_transfer` ends it).
    """

    def __init__(self, node: canopen.RemoteNode, desc: CanopenDescription, port: str, beat: Callable[[], None]):
        self.node = node
        self.desc = desc
        self.port = port
        self.beat = beat
        self.block_transfer = desc.block_transfer
        self.in_block_transfer = False

    # --- object access ----------------------------------------------------------------------

    def describe(self, addr: ObjectAddress) -> str:
        """``0x6072:0 (Max torque)``: an object as messages name it."""
        var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
        name = var.name if var is not None else "not in the EDS"
        if var is not None and var.parent is not None and not isinstance(var.parent, canopen.ObjectDictionary):
            name = f"{var.parent.name}: {var.name}"
        return f"{addr} ({name})"

    def eds_variable(self, addr: ObjectAddress) -> ODVariable:
        """The EDS entry of ``addr``; DeviceError when the EDS has none."""
        var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
        if var is None:
            raise DeviceError(f"{self.port}: object {addr} is not in the EDS {self.desc.eds}")
        return var

    def data_type(self, addr: ObjectAddress) -> int:
        """The CiA 301 data type the EDS gives ``addr``; DeviceError when it is not there or has none."""
        data_type = self.eds_variable(addr).data_type
        if data_type is None:
            raise DeviceError(f"{self.port}: the EDS {self.desc.eds} gives {self.describe(addr)} no data type")
        return data_type

    def _sdo_error(self, exc: Exception, addr: ObjectAddress, action: str) -> DeviceError:
        if isinstance(exc, SdoAbortedError):
            meaning = SdoAbortedError.CODES.get(exc.code, "unknown abort code")
            return DeviceError(f"{self.port}: SDO abort {action} {self.describe(addr)}: 0x{exc.code:08X} {meaning}")
        if isinstance(exc, SdoCommunicationError):
            return DeviceError(
                f"{self.port}: no valid SDO answer {action} {self.describe(addr)}: {exc} "
                "(is the drive powered, on this bus, with this node id?)"
            )
        return DeviceError(f"{self.port}: bus failure {action} {self.describe(addr)}: {exc}")

    def read_object(self, addr: ObjectAddress) -> ObjectValue:
        """Upload one object and decode it by its EDS data type."""
        var = self.eds_variable(addr)
        self.beat()
        try:
            raw = self._exchange(lambda: self.node.sdo.upload(addr.index, addr.subindex))
            return var.decode_raw(raw)
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, "reading") from None

    def write_object(self, addr: ObjectAddress, value: ObjectValue) -> None:
        """Download one object, encoded by its EDS data type."""
        var = self.eds_variable(addr)
        try:
            data = var.encode_raw(value)
        except (ValueError, TypeError, struct_error) as exc:
            raise DataError(f"{self.port}: value {value!r} does not fit {self.describe(addr)}: {exc}") from None
        self.beat()
        try:
            self._exchange(lambda: self.node.sdo.download(addr.index, addr.subindex, data))
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, "writing") from None

    def _exchange(self, request: Callable[[], _Result]) -> _Result:
        """One expedited or segmented exchange; asked once more when the answer was a stale frame.

        The answer canopen rejected belonged to an earlier exchange (a late
        segment of an aborted block upload, a late answer to a request it gave
        up on), so the channel is drained of late frames and the request sent
        again. Reads and the set-value writes hilident makes are idempotent.
        """
        try:
            with uninterruptible():
                return request()
        except SdoCommunicationError as exc:
            if not _out_of_step(exc):
                raise
            drain_stale_answers(self.node.sdo)
            with uninterruptible():
                return request()

    def read(self, role: str) -> ObjectValue:
        return self.read_object(self.desc.address(role))

    def write(self, role: str, value: ObjectValue) -> None:
        self.write_object(self.desc.address(role), value)

    def read_domain(self, addr: ObjectAddress, block_transfer: bool | None = None) -> bytes:
        """Upload a DOMAIN object, by block transfer when ``block_transfer`` says so (None: when
        :attr:`block_transfer` does)."""
        if not (self.block_transfer if block_transfer is None else block_transfer):
            try:
                with uninterruptible():
                    return bytes(self.node.sdo.upload(addr.index, addr.subindex))
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                raise self._sdo_error(exc, addr, "reading") from None

        def upload(f: BlockUploadStream) -> bytes:
            chunks: list[bytes] = []
            while True:
                with uninterruptible():
                    chunk = f.read(io.DEFAULT_BUFFER_SIZE)
                if not chunk:
                    return b"".join(chunks)
                chunks.append(bytes(chunk))

        return self._block_transfer(addr, "rb", upload, {})

    def write_domain(self, addr: ObjectAddress, data: bytes) -> None:
        """Download a DOMAIN object (block transfer when :attr:`block_transfer` says so)."""
        if not self.block_transfer:
            try:
                with uninterruptible():
                    self.node.sdo.download(addr.index, addr.subindex, data, force_segment=True)
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                raise self._sdo_error(exc, addr, "writing") from None
            return

        def download(f: BlockDownloadStream) -> None:
            view = memoryview(data)
            pos = 0
            while pos < len(data):
                with uninterruptible():
                    pos += f.write(view[pos : pos + 7])

        self._block_transfer(addr, "wb", download, {"size": len(data)})

    def _block_transfer(
        self, addr: ObjectAddress, mode: str, body: Callable[[_Stream], _Result], options: dict[str, int]
    ) -> _Result:
        """Run ``body(stream)`` on an SDO block transfer stream; an interrupted transfer is aborted.

        A signal (or any exception not from the transfer itself) in the middle
        of a block download leaves the drive's SDO server reading sub-block
        segments, where every frame but an abort counts as data: the next
        request (the Disable Voltage of ``safe_stop``) would be swallowed. So
        the transfer is ended with an SDO abort, never with canopen's normal
        close, which would send the end-of-transfer request and wait for it.

        A signal is raised between the segments ``body`` exchanges, never
        within one (each runs :func:`~hilident.endings.uninterruptible`):
        canopen's SDO client holds its response queue's lock while it waits,
        and an exception landing there would leave it locked for the Disable
        Voltage that follows.
        """
        action = "reading" if mode == "rb" else "writing"
        try:
            with shielded():  # a signal during the initiation is raised below, once the abort would be sent
                stream = self.node.sdo.open(
                    addr.index, addr.subindex, mode, block_transfer=True, buffering=0, **options
                )
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, action) from None
        self.in_block_transfer = True
        try:
            raise_pending()
            result = body(stream)
        except BaseException as exc:
            self.in_block_transfer = False
            io.RawIOBase.close(stream)  # closed without the end-of-transfer exchange
            cause = _transfer_error(exc)
            if not isinstance(cause, SdoAbortedError):  # the drive aborted: its server is idle already
                with contextlib.suppress(Exception):
                    self.node.sdo.abort(_ABORT_GENERAL)
                drain_stale_answers(self.node.sdo)
            if cause is not None:
                raise self._sdo_error(cause, addr, action) from None
            raise
        self.in_block_transfer = False
        try:
            with uninterruptible():
                stream.close()
        except Exception as exc:
            cause = _transfer_error(exc)
            if cause is None:
                raise
            raise self._sdo_error(cause, addr, action) from None
        return result

    def abort_interrupted_transfer(self) -> None:
        """End a block transfer that a signal handler interrupted with an SDO abort.

        The drive's SDO server reads sub-block segments until the transfer ends,
        taking every frame but an abort for data: a request sent now (the
        Disable Voltage of a safe stop) would be swallowed.
        """
        if self.in_block_transfer:
            self.node.sdo.abort(_ABORT_GENERAL)
