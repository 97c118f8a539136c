"""Driver descriptions: a device's ``driver.toml`` loaded and checked, and the tools that write one from a
vendor EDS.

May import ``config``, ``protocol``, ``filters`` and ``signals``; never ``adapters``, ``emulator`` or ``session`` (the
command line opens the twin ``drivers check`` tries a filter slot on: :mod:`hilident.cli.driver_trial`).
"""
