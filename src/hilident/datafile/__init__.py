"""Recordings made elsewhere: hilident HDF5, CSV or MATLAB ``.mat``, mapped onto named signals.

The ``[data]`` table of a configuration says which column (or variable) holds
the torque, velocity, position, output and excitation, how to scale each to SI
units, and the sample rate or the time column. Everything is checked here, so
the numerics downstream only see finite, equally long, gap-free, uniformly
sampled arrays; anything else is a :class:`~hilident.errors.DataError` naming
the file and the column.

Reading is bounded: only the mapped columns are read, CSV in chunks into
arrays sized from the file before anything is allocated, and the sizes an
HDF5 or ``.mat`` file declares are checked against the file and against
:data:`MAX_DATA_BYTES` before a byte of data is read. A hostile or damaged
file is one :class:`DataError`, never a traceback.

Gaps are found, never spliced over: a hilident recording numbers its rows
(``sample_index``), a time column shows a gap as a step of a whole number of
sample periods. :func:`hilident.pipeline.selection.select_gap_free` then keeps whole
gap-free excitation periods (when the recording says its excitation was
periodic) or the longest gap-free stretch.

Layout
------
- :mod:`~hilident.datafile.mapping`: :func:`load_dataset` and :class:`Dataset`,
  the column mapping, gaps, sample rate and whole periods
- :mod:`~hilident.datafile.columns`: :func:`read_columns` (by format) and
  :func:`read_friction_test`
- :mod:`~hilident.datafile.csv_reader`, :mod:`~hilident.datafile.mat_reader`,
  :mod:`~hilident.datafile.run_reader`: one reader per format (hilident run
  files: also :func:`read_run_info`)
- :mod:`~hilident.datafile.raw`: :class:`RawColumns`, the memory bound
  (:data:`MAX_DATA_BYTES`, to be changed there) and one-line messages

May import ``config``, ``io``, ``ident`` and ``pipeline``; never ``session``, ``adapters``, ``emulator`` or ``cli``.
"""

from hilident.datafile.columns import read_columns, read_friction_test
from hilident.datafile.csv_reader import CSV_CHUNK_LINES
from hilident.datafile.mapping import MIN_SAMPLES, RATE_TOLERANCE, Dataset, load_dataset
from hilident.datafile.raw import (
    MAX_COMPRESSION_RATIO,
    MAX_DATA_BYTES,
    RawColumns,
    memory_limit_bytes,
)
from hilident.datafile.run_reader import RunInfo, read_run_info

__all__ = [
    "CSV_CHUNK_LINES",
    "MAX_COMPRESSION_RATIO",
    "MAX_DATA_BYTES",
    "MIN_SAMPLES",
    "RATE_TOLERANCE",
    "Dataset",
    "RawColumns",
    "RunInfo",
    "load_dataset",
    "memory_limit_bytes",
    "read_columns",
    "read_friction_test",
    "read_run_info",
]
