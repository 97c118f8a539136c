"""The host side of the myRIO-style board on a serial line (COBS frames, PROTOCOL.md).

May import ``protocol``, ``drivers``, ``events``; never ``emulator``.
"""
