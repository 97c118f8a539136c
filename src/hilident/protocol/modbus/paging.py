"""Paged windows: how the excitation table and the capture buffer, longer than the address space, are moved.

The excitation table and the capture buffer are longer than the 16-bit address
space allows. Each is shown through a window of ``page_samples`` samples at
``base``; a page register (``table_page``, ``capture_page``) selects which page
the window shows. Sample ``k`` lies on page ``k // page_samples`` at window
offset ``(k % page_samples) * registers_per_sample``. A capture record is a
``u16`` stamp (sample index modulo :data:`STAMP_MODULUS`) followed by the
selected channels, so a host can prove that every record it read is the one it
asked for; the drive reports the CRC of the table (:func:`table_crc`) so the
host can prove the whole table arrived.

All functions are pure: numbers in, numbers out.

Examples
--------
>>> [c.samples for c in plan_chunks(0, 130, 2, 1024, 123)]
[61, 61, 8]
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError
from hilident.protocol.modbus.codecs import TYPES

__all__ = ["STAMP_MODULUS", "CaptureChannel", "Chunk", "Window", "plan_chunks", "table_crc"]

#: A capture record's stamp is its sample index modulo this (it is one u16 register).
STAMP_MODULUS = 1 << 16


@dataclass(frozen=True)
class Window:
    """A paged window onto a buffer longer than the address space.

    Attributes
    ----------
    name : {"table", "capture"}
    base : int
        Address of the window's first register.
    page_samples : int
        Samples per page.
    capacity_samples : int
        Samples the drive's buffer holds (the emulated drive's size; a host
        reads the ``*_capacity`` register).
    registers : int
        Size of the window in registers.
    page_register : str
        Register that selects the page.
    """

    name: str
    base: int
    page_samples: int
    capacity_samples: int
    registers: int
    page_register: str

    @property
    def end(self) -> int:
        return self.base + self.registers

    @property
    def pages(self) -> int:
        return -(-self.capacity_samples // self.page_samples)


@dataclass(frozen=True)
class CaptureChannel:
    """One channel of a capture record: name, on-wire type and scale; ``bit`` in ``capture_mask``."""

    name: str
    type: str
    scale: float
    bit: int

    @property
    def count(self) -> int:
        return TYPES[self.type][0]


@dataclass(frozen=True)
class Chunk:
    """One request of a paged transfer.

    Attributes
    ----------
    page : int
        Page to select before the request.
    offset : int
        Register offset of the request within the window.
    first_sample, samples : int
        Samples the request carries.
    count : int
        Registers the request carries.
    """

    page: int
    offset: int
    first_sample: int
    samples: int
    count: int


def plan_chunks(
    first_sample: int, n_samples: int, registers_per_sample: int, page_samples: int, max_registers: int
) -> list[Chunk]:
    """Requests that move samples ``first_sample .. first_sample + n_samples - 1`` through a paged window.

    Each request carries whole samples, at most ``max_registers`` registers,
    and stays on one page.

    Raises
    ------
    ConfigError
        One sample does not fit in one request.
    """
    per_request = max_registers // registers_per_sample
    if per_request < 1:
        raise ConfigError(
            "modbus.max_registers",
            f"a sample of {registers_per_sample} registers does not fit a request of {max_registers}",
        )
    chunks = []
    k, end = int(first_sample), int(first_sample) + int(n_samples)
    while k < end:
        page, within = divmod(k, page_samples)
        m = min(per_request, page_samples - within, end - k)
        chunks.append(Chunk(page, within * registers_per_sample, k, m, m * registers_per_sample))
        k += m
    return chunks


def table_crc(registers) -> int:
    """CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF) of ``registers`` sent big-endian.

    The drive reports it in ``table_crc`` so the host can prove the whole table
    arrived before it starts a run.
    """
    data = np.asarray(registers, dtype=np.int64).astype(">u2").tobytes()
    return binascii.crc_hqx(data, 0xFFFF)
