"""The host side of a CiA 402 drive on CANopen: one adapter and the parts it owns.

May import ``protocol``, ``drivers``, ``events``; never ``emulator``.
"""
