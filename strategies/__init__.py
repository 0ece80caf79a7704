"""Built-in pruning strategies, one module per plugin (registered as ``pocketbench.strategies`` entry points).

``none`` (the LSG-SLAM baseline), ``pocket`` (Pocket-SLAM: rendering-area score with per-tile
budgets), ``area`` (the same score with one global budget), ``opacity`` (LightGaussian),
``gradient`` (LP-3DGS as the paper describes it) and ``mask`` (MaskGaussian). The core never
imports this package: it finds each class through its entry point, exactly as it finds a
third-party plugin, so the built-ins get no privileges a plugin would not have.
"""
