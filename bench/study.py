"""``python -m bench.study``: the runs of a study (conf/study/NAME.yaml); the command lives in ``bench.sweep.study``."""

import sys

from bench.sweep.study import main

if __name__ == "__main__":
    sys.exit(main())
