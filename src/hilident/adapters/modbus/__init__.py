"""The host side of a Modbus drive (TCP or RTU): one adapter and the parts it owns.

May import ``protocol``, ``drivers``, ``events``; never ``emulator``.
"""
