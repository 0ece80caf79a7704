"""``python -m bench.view``: a run's map in the browser; the command lives in ``bench.viewer.cli``."""

import sys

from bench.viewer.cli import main

if __name__ == "__main__":
    sys.exit(main())
