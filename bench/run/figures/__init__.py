"""The figures a run draws into its own dir, beside its metrics.json: ``run_memory`` (the memory timeline)
and ``pruned_run`` (``viz.pruning``: what a prune removed). A report's figures are ``bench.report.figures``."""
