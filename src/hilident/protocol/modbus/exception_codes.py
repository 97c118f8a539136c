"""What the exception code of a Modbus answer means (Modbus Application Protocol V1.1b3, section 7).

>>> exception_meaning(2)
'illegal data address: no such register, or it is not writable'
"""

from __future__ import annotations

__all__ = ["EXCEPTION_MEANINGS", "exception_meaning"]

#: Meaning of each Modbus exception code (Modbus Application Protocol V1.1b3, section 7).
EXCEPTION_MEANINGS: dict[int, str] = {
    1: "illegal function: the drive does not offer this request",
    2: "illegal data address: no such register, or it is not writable",
    3: "illegal data value: the value is out of range or not allowed in this state",
    4: "server device failure: the drive could not carry out the request",
    5: "acknowledge: accepted, still being processed",
    6: "server device busy: try again later",
    7: "negative acknowledge",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


def exception_meaning(code: int) -> str:
    """What Modbus exception ``code`` means."""
    return EXCEPTION_MEANINGS.get(int(code), "not a standard Modbus exception code")
