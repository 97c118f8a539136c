"""``hilident batch``: many recordings identified in parallel on Dask, one table row each.

:mod:`~hilident.batch.inputs` turns the command's arguments into recordings
and hashes them; :mod:`~hilident.batch.identity` says which axis and device a
recording is of and when it was made; :mod:`~hilident.batch.task` identifies one recording into
one row (never raising); :mod:`~hilident.batch.table` reads and writes the
table (``batch.parquet`` and ``batch.csv``); :mod:`~hilident.batch.runner`
runs the tasks on a Dask cluster or in a plain loop, skipping what the table
already holds; :mod:`~hilident.batch.verdicts` judges every axis's drift from
the whole table and writes ``drift.json`` and ``report.html``.

May import ``config``, ``io``, ``ident``, ``html_report``, ``emulator`` (the fleet's twins) and ``session`` (one
recording identified as ``hilident identify`` does); never ``cli``.
"""
