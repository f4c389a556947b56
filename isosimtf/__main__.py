"""``python -m isosimtf``: the same as the ``isosimtf`` command."""

from .cli import console_main

if __name__ == "__main__":  # not when a process pool's child imports the main module again
    console_main()
