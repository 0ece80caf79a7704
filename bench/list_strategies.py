"""``python -m bench.list_strategies``: installed pruning strategies (the command: ``bench.cli.list_strategies``)."""

import sys

from bench.cli.list_strategies import main

if __name__ == "__main__":
    sys.exit(main())
