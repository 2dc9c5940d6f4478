"""``python -m piezohyst.cli``: the same as the ``piezohyst`` command."""

import sys

from . import main

sys.exit(main())
