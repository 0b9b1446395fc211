"""``python -m sumo_scendiff.run``: see :mod:`sumo_scendiff.run.cli`."""
import sys

from .cli import get_options, main

if __name__ == "__main__":
    sys.exit(main(get_options()))
