"""The examples and the exit-code list ``hilident --help`` and the commands' ``--help`` end with.

Kept apart from :mod:`hilident.cli.main` so the parser stays readable; plain text,
printed as written (``argparse.RawDescriptionHelpFormatter``).
"""

from __future__ import annotations

EXIT_CODES = """\
exit codes:
  0         success (also when the output pipe or terminal closed)
  2         configuration or usage error (names [table.key] and the file, or the flag), or not confirmed
  3         data error, or the disk filled
  4         device error: the port, object or register is named
  5         a safety limit tripped
  129/130/143  SIGHUP / SIGINT (Ctrl-C) / SIGTERM; the axis is stopped first
"""

TOP = (
    """\
first hour:
  hilident init --out axis.toml                     a commented config for the serial board (emulated)
  hilident init --transport canopen --out axis.toml  ... for a CiA 402 drive (--transport modbus: Modbus)
  hilident ports                                    serial ports and CAN channels for [device] port
  hilident drivers -v                               the drivers found: channels, rates, modes, filter slots
  hilident run axis.toml                            a whole session; results in runs/axis-<date>-<time>/
  hilident run configs/emulated-gantry.toml --out runs/gantry --overwrite

"""
    + EXIT_CODES
)

RUN = (
    """\
examples:
  hilident run configs/emulated-gantry.toml                   the emulated twin; results in runs/emulated-gantry-<time>/
  hilident run bench.toml --dry-run                           connect, check, print the plan; nothing moves
  hilident run bench.toml --yes --out runs/axis1 --overwrite  scripted, into a folder that holds an earlier run
  hilident --log-level debug run bench.toml                   with the library's log on stderr

"""
    + EXIT_CODES
)

IDENTIFY = (
    """\
examples:
  hilident identify runs/gantry/identification.h5              a hilident recording (its config is stored in it)
  hilident identify scope.csv --config axis.toml --out runs/axis
  hilident identify a.h5 --validation b.h5                     validate the [model] fit on a second record

"""
    + EXIT_CODES
)

BATCH = (
    """\
examples:
  hilident batch fleet/ --out fleet-table                    every recording under fleet/, on a local cluster
  hilident batch 'scopes/*.csv' --config axis.toml --out t   CSV exports: the config names their columns
  hilident batch fleet/ --out t --scheduler tcp://host:8786  on a running Dask cluster (docs/batch.md)
  hilident batch a.h5 --out t --scheduler synchronous        a plain loop in this process (debugging)

"""
    + EXIT_CODES
)

UPLOAD = (
    """\
examples:
  hilident upload --from runs/axis --config drive.toml --dry-run   what the drive would hold; nothing written
  hilident upload --from runs/axis --config drive.toml --yes --save

"""
    + EXIT_CODES
)
