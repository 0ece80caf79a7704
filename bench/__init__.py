"""pocketbench: a benchmark harness for Gaussian-pruning strategies in 3DGS SLAM."""

import os

# Idle OpenMP workers (torch's, numba's) sleep instead of spinning, unless the user chose: set here,
# before any module of the package loads torch and with it the OpenMP runtime, which reads the
# policy once. A spinning worker holds a core that a process beside it (a sweep's sibling job,
# another user's run) needs, so two runs side by side would each slow the other down.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
