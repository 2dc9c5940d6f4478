"""``python -m piezohyst``: the same as the ``piezohyst`` command."""

import sys

from .cli import main

sys.exit(main())
