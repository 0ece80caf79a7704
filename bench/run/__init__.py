"""One run, start to end: its config (``config``: the composition of every group's settings), their
validation (``validate``) and its identity (``identity``), its lifecycle and record, the frame loop and
what it leaves (``outcome``), evaluation, checkpoints and resume, signals, determinism, provenance, the
map export and the figures it draws into its own dir (``figures``)."""
