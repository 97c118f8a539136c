"""Files hilident writes and reads: HDF5 recordings, ``summary.json``, the JSON serialiser, export formats.

May import ``errors``, ``events``, ``units``; never ``session`` or ``cli``.
"""
