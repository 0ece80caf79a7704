"""pocketbench: a benchmark harness for Gaussian-pruning strategies in 3DGS SLAM."""

import os

# How long an idle OpenMP worker (torch's runtime and numba's, both libgomp) spins after a parallel region before
# it sleeps: set here, before any module of the package loads torch and with it the runtime, which reads it once.
# The runtime's own default spins for long (hundreds of thousands of iterations): fastest for a run that has the
# cores to itself, but a spinning worker holds a core that a process beside it (a sweep's sibling job, another
# user's run) needs. OMP_WAIT_POLICY=PASSIVE (no spin) protects the neighbour but costs a run alone a sleep and a
# wake-up on every region. A short spin keeps most of both (reports/speed/2026-11-28-omp-wait.md). A policy or a
# spin count the user set wins: an explicit GOMP_SPINCOUNT would override their OMP_WAIT_POLICY, so none is set then.
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "1000")
