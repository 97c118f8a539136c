"""Files hilident writes and reads: HDF5 recordings, ``summary.json``, the JSON serialiser, export formats.

May import ``config``, ``errors``, ``events`` and ``pipeline`` (the records written into ``summary.json``); never
``session``, ``adapters``, ``emulator`` or ``cli``.
"""
