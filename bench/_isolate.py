"""Imported first by every bench script: moves the bench folder to the end of ``sys.path``.

``python bench/X.py`` puts ``bench/`` first on ``sys.path``, where
``bench/canopen.py`` would be found instead of the ``canopen`` package that
hilident's CANopen adapter imports. It stays last, not gone: a process the
script spawns re-imports the script with this ``sys.path`` and needs this module.
"""

import os
import sys

_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [p for p in sys.path if os.path.abspath(p or os.curdir) != _HERE] + [_HERE]
