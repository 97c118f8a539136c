"""Run configurations: the one schema mechanism of every TOML file hilident reads, and the typed tables.

May import ``errors``, ``protocol`` (object addresses checked as a key is read) and the pure checks of ``signals``;
no I/O beyond reading the file.
"""
