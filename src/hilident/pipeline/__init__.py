"""Pure composition of the identification steps: recorded arrays in, models and filters out.

No files, no devices: the session hands arrays to these functions and writes
what they return. The same functions serve ``hilident run`` and ``hilident
identify`` on recordings made elsewhere. Each module is one step; import a
name from the module that defines it:

- :mod:`~hilident.pipeline.selection`: the gap-free rows of a recording
  (whole excitation periods, or the longest stretch);
- :mod:`~hilident.pipeline.friction`: the friction curve from the
  constant-velocity windows of the friction test;
- :mod:`~hilident.pipeline.responses`: frequency responses through the drive
  (loop, pooled records, filter slots with the plant);
- :mod:`~hilident.pipeline.plant`: one identification run: friction removed,
  plant and loop responses, resonances, the analysis band;
- :mod:`~hilident.pipeline.plant_model`: the transfer function fitted to the
  plant response and the resonances it confirms;
- :mod:`~hilident.pipeline.measurement`: how far the measurement can be
  trusted (uncertainty, resolution, input spectrum, sampling);
- :mod:`~hilident.pipeline.eligibility`: the evidence a resonance needs for a
  notch;
- :mod:`~hilident.pipeline.notches`: which resonances get a notch, and the
  notch designs;
- :mod:`~hilident.pipeline.verification`: measured reductions, the record's
  noise floor, what a device's stored section does;
- :mod:`~hilident.pipeline.records`: resonances, rejected peaks and notches as
  ``summary.json`` records;
- :mod:`~hilident.pipeline.greybox`: the ``[model]`` grey-box fit and its
  validation.

The package may import :mod:`hilident.config`, :mod:`hilident.errors`,
:mod:`hilident.ident` and :mod:`hilident.filters`, and nothing that does I/O
(no :mod:`hilident.io`, no :mod:`hilident.session`, no devices).
"""
