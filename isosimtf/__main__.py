"""``python -m isosimtf``: the same as the ``isosimtf`` command."""

import sys

from .cli import main

sys.exit(main())
