"""``python -m isosimtf``: the same as the ``isosimtf`` command."""

from .cli import console_main

console_main()
