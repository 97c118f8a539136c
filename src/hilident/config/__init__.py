"""Run configurations: the one schema mechanism of every TOML file hilident reads, and the typed tables.

May import ``errors``, ``numbers`` and the pure checks of ``signals``; no I/O beyond reading the file.
"""
