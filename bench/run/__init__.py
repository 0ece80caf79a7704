"""One run, start to end: its lifecycle and record, the frame loop, evaluation, checkpoints and resume,
signals, determinism, provenance and the map export."""
