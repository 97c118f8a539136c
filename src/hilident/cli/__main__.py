"""``python -m hilident.cli``: the ``hilident`` command, where its script is not on the path."""

import sys

from hilident.cli.main import main

sys.exit(main())
