"""The command line: argv checks (``argv``), ``--help`` (``help``), the Hydra entry (``entry``),
``python -m bench.list_strategies``. The settings are checked by ``bench.run.validate``, below it."""
