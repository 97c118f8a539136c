"""Figures of a run and of ``identify``, drawn with matplotlib's object API (Agg, no pyplot state).

:mod:`~hilident.plots.bode` (frequency responses with units, the analysis band,
coherence, the model and the designed and stored notch),
:mod:`~hilident.plots.friction` (friction points and the fitted curve with its
parameters), :mod:`~hilident.plots.greybox` (a grey-box model simulated
against the measurement, and its residual tests), :mod:`~hilident.plots.notches`
(the notch chain as designed and as stored), :mod:`~hilident.plots.map`
(the mode over the mapped positions), :mod:`~hilident.plots.moves` (a move
without and with the notch) and :mod:`~hilident.plots.drift` (a batch's resonance
and damping per axis over the days, the trend and its verdict), :mod:`~hilident.plots.stabilisation` (the
stabilisation diagram of the modes from several inputs and outputs). :mod:`~hilident.plots.figures`
draws a run's and an identification's set, :mod:`~hilident.plots.show` a recording over time (``hilident
show``). matplotlib is imported only inside the functions that draw.

May import ``errors``, ``events``, ``units``, ``io``, ``ident``, ``filters``, ``motion`` and ``pipeline``; never
``session``, ``adapters``, ``emulator`` or ``cli``.
"""
