"""``python -m bench``: the Hydra entry, nothing else (the run itself is ``bench.run.lifecycle.run``)."""

from __future__ import annotations

import sys

from bench.cli.entry import main

if __name__ == "__main__":
    sys.exit(main())
