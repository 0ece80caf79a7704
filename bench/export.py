"""``python -m bench.export``: a run's map as PLY; the command lives in ``bench.run.export``."""

import sys

from bench.run.export import main

if __name__ == "__main__":
    sys.exit(main())
