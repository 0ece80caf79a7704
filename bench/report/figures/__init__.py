"""Every figure of a report, one module per figure family (a run's own figures are ``bench.run.figures``).

Per report (``make.make_plots``): ``per_keyframe``,
``trajectory``, ``density``, ``pruned``, ``milestones``, ``drift``, ``ratio``, ``pareto``, over the
readers in ``runs`` and the file settings in ``output``.

Built on ``matplotlib.figure.Figure`` rather than pyplot: no global backend switch (Agg is
used for PNG regardless) and no figure left open in a caller's session. Each plot reads only
the run dir files the harness writes; a missing or malformed file costs that line a warning,
never the report. Per-sequence figures take the whole dataset's runs plus a sequence, so labels,
colours and markers match the tables and each other. The visual language (a colour per strategy,
panels per preset, legends outside, seeds as bands) is ``bench.report.style``'s.
"""
