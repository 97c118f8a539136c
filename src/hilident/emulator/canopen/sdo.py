"""SDO server of the emulated CANopen drive: expedited, segmented and block transfer.

canopen's :class:`~canopen.sdo.SdoServer` answers expedited and segmented
transfers only: it turns a block upload into a segmented one (which canopen's
own block-upload client rejects) and aborts every block download. A drive that
holds an excitation table and a capture buffer of hundreds of kilobytes needs
block transfer (CiA 301, 7.2.4.3.9-16), so this server adds both directions,
with the CRC (CRC-16/XMODEM) when the client asks for it and retransmission
from the last acknowledged segment.

It also injects the ``abort_object`` fault: every access to one object (or one
sub-index) aborts with 0x06060000, "access failed due to a hardware error".

A failure while serving an object (a value the object dictionary cannot
encode, a bug in a callback) aborts that transfer with 0x08000000 and is one
warning in the log naming the object, its traceback at debug level: never a
traceback on the terminal (canopen's server would log it with
``logger.exception``).
"""

from __future__ import annotations

import binascii
import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from canopen.sdo import SdoAbortedError, SdoServer
from canopen.sdo.constants import (
    ABORT_CRC_ERROR,
    ABORT_GENERAL_ERROR,
    ABORT_INVALID_BLOCK_SIZE,
    ABORT_INVALID_COMMAND_SPECIFIER,
    ABORT_NOT_IN_OD,
    REQUEST_ABORTED,
    REQUEST_BLOCK_DOWNLOAD,
    REQUEST_BLOCK_UPLOAD,
    REQUEST_DOWNLOAD,
    REQUEST_UPLOAD,
    RESPONSE_BLOCK_DOWNLOAD,
    RESPONSE_BLOCK_UPLOAD,
    SDO_STRUCT,
)

logger = logging.getLogger(__name__)
# canopen's records reach the log's handlers (--log-level), never Python's last-resort printer on stderr
logging.getLogger("canopen").addHandler(logging.NullHandler())

ABORT_HARDWARE = 0x06060000
# CiA 301 SDO abort codes the emulated drive answers with
ABORT_VALUE = 0x06090030
ABORT_TOO_HIGH = 0x06090031
ABORT_TOO_LOW = 0x06090032
ABORT_STATE = 0x08000022
ABORT_NO_DATA = 0x08000024
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_INCOMPATIBLE = 0x06040043  # general parameter incompatibility (a producer in two consumer entries)
#: Segments per block this server asks for / sends at most (CiA 301 allows 1..127).
BLOCK_SIZE = 127

_CRC = 0x04
_SIZE = 0x02
_NO_MORE = 0x80


def crc16(data: bytes | bytearray) -> int:
    """CRC-16/XMODEM of ``data``, as SDO block transfer uses it."""
    return binascii.crc_hqx(bytes(data), 0)


def parse_fault_object(text: str) -> tuple[int, int | None] | None:
    """``"0x3100"`` -> (0x3100, None) (every sub-index), ``"0x3100:2"`` -> (0x3100, 2), ``""`` -> None."""
    text = (text or "").strip()
    if not text:
        return None
    head, _, tail = text.partition(":")
    return int(head, 16), (int(tail, 0) if tail else None)


@dataclass
class _BlockUpload:
    """A block upload in progress (server to client).

    Attributes
    ----------
    data : bytes
        The object's value, all of it.
    crc : bool
        The client asked for a CRC at the end.
    blksize : int
        Segments per sub-block the client takes.
    pos : int
        Bytes the client acknowledged.
    block_start : int
        Byte offset of the sub-block last sent.
    sent : int
        Segments in that sub-block.
    last_sent : bool
        That sub-block held the last byte.
    ended : bool
        The end was sent; the client's confirmation closes the transfer.
    """

    data: bytes
    crc: bool
    blksize: int
    pos: int = 0
    block_start: int = 0
    sent: int = 0
    last_sent: bool = False
    ended: bool = False


@dataclass
class _BlockDownload:
    """A block download in progress (client to server).

    Attributes
    ----------
    crc : bool
        The client sends a CRC at the end.
    size : int or None
        The size the client announced, bytes.
    buffer : bytearray
        Segment data received so far (7 bytes a segment).
    seq : int
        Last segment received in order in this sub-block.
    done : bool
        The last segment arrived.
    ended : bool
        Every segment is in; the client's end request (unused bytes, CRC) completes the transfer.
    """

    crc: bool
    size: int | None
    buffer: bytearray = field(default_factory=bytearray)
    seq: int = 0
    done: bool = False
    ended: bool = False


class BlockSdoServer(SdoServer):
    """SdoServer with block upload and block download.

    Parameters
    ----------
    rx_cobid, tx_cobid : int
        COB-IDs of requests (0x600 + node) and responses (0x580 + node).
    node : canopen.LocalNode
    abort_object : (index, subindex or None) or None
        Every transfer touching it is aborted (fault injection).
    """

    def __init__(self, rx_cobid: int, tx_cobid: int, node, abort_object: tuple[int, int | None] | None = None):
        super().__init__(rx_cobid, tx_cobid, node)
        self.abort_object = abort_object
        self._index = 0
        self._subindex = 0
        self._block: _BlockUpload | _BlockDownload | None = None  # a block transfer in progress
        self.aborted_by_fault = 0
        #: ``size_limit(index, subindex) -> int or None``: largest download the object takes, in bytes
        self.size_limit: Callable[[int, int], int | None] | None = None

    # --- dispatch -------------------------------------------------------------------------

    def on_request(self, can_id, data, timestamp):
        data = bytes(data)
        if len(data) < 8:
            data = data.ljust(8, b"\0")
        block = self._block
        if isinstance(block, _BlockDownload) and not block.ended and data[0] != REQUEST_ABORTED:
            # sub-block segments carry a sequence number (1..127, bit 7: last), not a command; only an
            # abort (0x80 exactly: sequence number 0 does not exist) interrupts them
            self._download_segment(block, data)
            return
        if block is not None and data[0] & 0xE0 == REQUEST_ABORTED:
            self._block = None
        refusal = self._refusal(data)
        if refusal is not None:
            self._block = None
            self.abort(refusal)
            return
        ccs = data[0] & 0xE0
        if ccs in (REQUEST_BLOCK_UPLOAD, REQUEST_BLOCK_DOWNLOAD):
            self._block_request(ccs, data)
            return
        super().on_request(can_id, data, timestamp)

    def _refusal(self, data: bytes) -> int | None:
        """The abort code that refuses a request initiating a transfer (None: served).

        An object with the abort fault switched on is refused with a hardware
        error; a download whose announced size does not fit the object before
        a byte is sent.
        """
        ccs = data[0] & 0xE0
        initiate = (
            ccs in (REQUEST_UPLOAD, REQUEST_DOWNLOAD)
            or (ccs == REQUEST_BLOCK_UPLOAD and data[0] & 0x03 == 0)
            or (ccs == REQUEST_BLOCK_DOWNLOAD and data[0] & 0x01 == 0)
        )
        if not initiate:
            return None
        _, index, sub = SDO_STRUCT.unpack_from(data)
        if self._faulty(index, sub):
            self._index, self._subindex = index, sub
            self.aborted_by_fault += 1
            return ABORT_HARDWARE
        sized = (ccs == REQUEST_DOWNLOAD and data[0] & 0x03 == 0x01) or (
            ccs == REQUEST_BLOCK_DOWNLOAD and data[0] & _SIZE
        )  # segmented / block download with a size
        if not sized:
            return None
        size = struct.unpack_from("<L", data, 4)[0]  # announced size of a segmented or block download
        limit = self.size_limit(index, sub) if self.size_limit else None
        if limit is not None and size > limit:
            self._index, self._subindex = index, sub
            return ABORT_LENGTH_HIGH  # refused before a byte is sent, as the data would not fit
        return None

    def _block_request(self, ccs: int, data: bytes) -> None:
        """A block upload or download request; a failure aborts the transfer and the server goes on."""
        try:
            if ccs == REQUEST_BLOCK_UPLOAD:
                self._block_upload(data)
            else:
                self._block_download(data)
        except SdoAbortedError as exc:
            self._block = None
            self.abort(exc.code)
        except KeyError:
            self._block = None
            self.abort(ABORT_NOT_IN_OD)
        except Exception as exc:  # keep serving; the transfer is aborted
            self._log_failure(exc)
            self._block = None
            self.abort(ABORT_GENERAL_ERROR)

    # --- canopen's transfers, their failures one log line -------------------------------------

    def init_upload(self, request):
        self._served(super().init_upload, request)

    def segmented_upload(self, command):
        self._served(super().segmented_upload, command)

    def init_download(self, request):
        self._served(super().init_download, request)

    def segmented_download(self, command, request):
        self._served(super().segmented_download, command, request)

    def _served(self, step: Callable, *args) -> None:
        """Run one step of canopen's transfer; an unexpected failure becomes a general-error abort."""
        try:
            step(*args)
        except (SdoAbortedError, KeyError):
            raise  # canopen answers these with their own abort codes
        except Exception as exc:
            self._log_failure(exc)
            raise SdoAbortedError(ABORT_GENERAL_ERROR) from None

    def _log_failure(self, exc: Exception) -> None:
        """One warning naming the object the transfer was serving; the traceback at debug level."""
        logger.warning(
            "SDO 0x%04X:%d: %s: %s; aborted with 0x%08X",
            self._index or 0,
            self._subindex or 0,
            type(exc).__name__,
            exc,
            ABORT_GENERAL_ERROR,
        )
        logger.debug("SDO 0x%04X:%d failed", self._index or 0, self._subindex or 0, exc_info=exc)

    def _faulty(self, index: int, sub: int) -> bool:
        f = self.abort_object
        return f is not None and f[0] == index and (f[1] is None or f[1] == sub)

    # --- block upload (server -> client) ------------------------------------------------------

    def _block_upload(self, data: bytes) -> None:
        cs = data[0] & 0x03
        block = self._block
        if cs == 0:  # initiate
            _, index, sub = SDO_STRUCT.unpack_from(data)
            self._index, self._subindex = index, sub
            blksize = data[4]
            if not 0 < blksize <= BLOCK_SIZE:
                raise SdoAbortedError(ABORT_INVALID_BLOCK_SIZE)
            payload = bytes(self._node.get_data(index, sub, check_readable=True))
            self._block = _BlockUpload(payload, crc=bool(data[0] & _CRC), blksize=blksize)
            response = bytearray(8)
            SDO_STRUCT.pack_into(response, 0, RESPONSE_BLOCK_UPLOAD | _CRC | _SIZE, index, sub)
            struct.pack_into("<L", response, 4, len(payload))
            self.send_response(response)
        elif cs == 1 and isinstance(block, _BlockUpload) and block.ended:  # client confirms the end
            self._block = None
        elif not isinstance(block, _BlockUpload) or block.ended:
            raise SdoAbortedError(ABORT_INVALID_COMMAND_SPECIFIER)
        elif cs == 3:  # start
            self._send_upload_block(block)
        elif cs == 2:  # block acknowledged
            ackseq, blksize = data[1], data[2]
            if not 0 < blksize <= BLOCK_SIZE:
                raise SdoAbortedError(ABORT_INVALID_BLOCK_SIZE)
            block.pos = min(block.block_start + 7 * ackseq, len(block.data))
            block.blksize = blksize
            if ackseq < block.sent:
                self._send_upload_block(block)  # retransmit from the first unacknowledged segment
            elif block.pos >= len(block.data) and block.last_sent:
                n_unused = 7 - (len(block.data) - 7 * ((len(block.data) - 1) // 7)) if block.data else 7
                response = bytearray(8)
                response[0] = RESPONSE_BLOCK_UPLOAD | (n_unused << 2) | 0x01
                struct.pack_into("<H", response, 1, crc16(block.data) if block.crc else 0)
                block.ended = True
                self.send_response(response)
            else:
                self._send_upload_block(block)
        else:
            raise SdoAbortedError(ABORT_INVALID_COMMAND_SPECIFIER)

    def _send_upload_block(self, block: _BlockUpload) -> None:
        payload = block.data
        pos = block.block_start = block.pos
        seq = 0
        last = False
        while seq < block.blksize and not last:
            chunk = payload[pos : pos + 7]
            seq += 1
            pos += 7
            last = pos >= len(payload)
            frame = bytearray(8)
            frame[0] = seq | (_NO_MORE if last else 0)
            frame[1 : 1 + len(chunk)] = chunk
            self.send_response(frame)
        block.sent = seq
        block.last_sent = last

    # --- block download (client -> server) ----------------------------------------------------

    def _block_download(self, data: bytes) -> None:
        cs = data[0] & 0x01
        block = self._block
        if cs == 0:  # initiate
            _, index, sub = SDO_STRUCT.unpack_from(data)
            self._index, self._subindex = index, sub
            obj = self._node._find_object(index, sub)
            if not obj.writable:
                raise SdoAbortedError(0x06010002)
            size = struct.unpack_from("<L", data, 4)[0] if data[0] & _SIZE else None
            self._block = _BlockDownload(crc=bool(data[0] & _CRC), size=size)
            response = bytearray(8)
            SDO_STRUCT.pack_into(response, 0, RESPONSE_BLOCK_DOWNLOAD | _CRC, index, sub)
            response[4] = BLOCK_SIZE
            self.send_response(response)
        elif isinstance(block, _BlockDownload) and block.ended:  # end: bytes unused, CRC
            n_unused = (data[0] >> 2) & 0x07
            buffer = block.buffer
            if n_unused:
                del buffer[len(buffer) - n_unused :]
            if block.crc and struct.unpack_from("<H", data, 1)[0] != crc16(buffer):
                raise SdoAbortedError(ABORT_CRC_ERROR)
            self._block = None
            self._node.set_data(self._index, self._subindex, bytes(buffer), check_writable=True)
            response = bytearray(8)
            response[0] = RESPONSE_BLOCK_DOWNLOAD | 0x01
            self.send_response(response)
        else:
            raise SdoAbortedError(ABORT_INVALID_COMMAND_SPECIFIER)

    def _download_segment(self, block: _BlockDownload, data: bytes) -> None:
        seqno = data[0] & 0x7F
        last = bool(data[0] & _NO_MORE)
        if seqno == block.seq + 1:
            block.seq = seqno
            block.buffer += data[1:8]
            block.done = last
        # else: a lost or repeated segment; the acknowledgement below asks for it again
        if last or seqno >= BLOCK_SIZE:
            response = bytearray(8)
            response[0] = RESPONSE_BLOCK_DOWNLOAD | 0x02
            response[1] = block.seq
            response[2] = BLOCK_SIZE
            if block.done:
                block.ended = True
            block.seq = 0
            self.send_response(response)
