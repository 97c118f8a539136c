"""Driver descriptions: a device's ``driver.toml`` loaded and checked, and the tools that write one from a
vendor EDS.

May import ``config``, ``protocol`` and ``signals``; never ``adapters``, ``emulator`` or ``session``.
"""
