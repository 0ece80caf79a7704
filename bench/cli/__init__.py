"""The command line: argv checks and the Hydra entry (``entry``), the settings checked before any work
(``validate``), ``python -m bench.list_strategies``."""
