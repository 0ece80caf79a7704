"""Test-only: ``POCKETBENCH_TEST_SIGNAL_AT=FRAME:SIGNAL`` makes a run that started at frame 0 send itself
SIGNAL once frame FRAME's rows (and checkpoint, if that frame wrote one) are on disk.

Python imports this file at start-up when its folder is on ``PYTHONPATH``, as ``tests/test_checkpoint.py``
puts it for the runs it stops (a submitit job inherits it), so the product's frame loop carries no
test hook. It wraps the progress bar's ``update``, which the frame loop calls once per frame right
after that frame's rows and checkpoint are written and before it looks for a held preemption.
"""

import os

_SPEC = os.environ.get("POCKETBENCH_TEST_SIGNAL_AT")

if _SPEC:
    import signal

    from bench.measure import progress

    _frame, _, _name = _SPEC.partition(":")
    _AT, _SIGNUM = int(_frame), int(getattr(signal, "SIG" + (_name or "KILL")))
    _update = progress.Phase.update

    def _update_then_signal(self, n=1, **postfix):
        if not hasattr(self, "_started_at_zero"):  # a resumed run's first update jumps to its checkpoint, no postfix
            self._started_at_zero = bool(postfix)
        _update(self, n, **postfix)
        if self._started_at_zero and self.desc == "frames" and self.done == _AT + 1:
            os.kill(os.getpid(), _SIGNUM)

    progress.Phase.update = _update_then_signal
