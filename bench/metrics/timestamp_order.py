"""Timestamp order checks shared by the trajectory reader and the dataset lists.

Why an error and not a silent sort: evo associates and differentiates in file order, so a
duplicate or out-of-order row changes ATE and RPE without a word (a conflicting duplicate in a
TUM fr2/desk estimate moved ATE by a factor of about 30). The caller names the file and line.
"""

from __future__ import annotations

import numpy as np


def order_problem(stamps_s: np.ndarray, line_numbers: list[int], allow_equal: bool = False) -> str | None:
    """None if ``stamps_s`` [N] strictly increase (or, with ``allow_equal``, never decrease), else
    'line L: ...' for the first offending row."""
    stamps_s = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
    if stamps_s.size < 2:
        return None
    diff = np.diff(stamps_s)
    bad = np.flatnonzero(diff < 0 if allow_equal else diff <= 0)
    if bad.size == 0:
        return None
    i = int(bad[0]) + 1  # the row that breaks the order
    t, prev = stamps_s[i], stamps_s[i - 1]
    line, prev_line = line_numbers[i], line_numbers[i - 1]
    if t == prev:
        return (
            f"line {line}: expected strictly increasing timestamps, found {t:.9f} again (duplicate of line {prev_line})"
        )
    return f"line {line}: expected strictly increasing timestamps, found {t:.9f} after {prev:.9f} (line {prev_line})"
