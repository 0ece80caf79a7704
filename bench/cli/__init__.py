"""The command line: argv checks (``argv``), ``--help`` (``help``), the Hydra entry (``entry``), the settings
checked before any work (``validate``), ``python -m bench.list_strategies``."""
