"""``+KEY`` under a typed group is held to the group's schema like any other key (issue 62, H).

Hydra's ``+`` adds a key even to a typed (structured) node, so ``+slam.mapping_iterz=5`` composed, changed
the config hash and nothing else. The same typo without ``+`` was refused; now both are, with the closest name.
"""

from __future__ import annotations

import pytest

from tests.test_bad_input import run_cli

CASES = {
    "slam": (["+slam.mapping_iterz=5"], "slam has no setting 'mapping_iterz'", "did you mean 'mapping_iters'?"),
    "slam-nested": (["+slam.lrs.meanz=1"], "slam.lrs has no setting 'meanz'", "did you mean 'means'?"),
    "strategy-group": (
        ["+strategy=pocket", "+strategy.parms.area=analytic"],
        "strategy has no setting 'parms'",
        "did you mean 'params'?",
    ),
    "strategy-params": (
        ["+strategy=pocket", "+strategy.params.aera=analytic"],
        "strategy 'pocket': expected parameters among area,",
        "did you mean 'area'?",
    ),
    "dataset": (["+dataset.n_frame=5"], "dataset has no setting 'n_frame'", "did you mean 'n_frames'?"),
    "prune": (["+prune.keep_ratioo=0.5"], "prune has no setting 'keep_ratioo'", "did you mean 'keep_ratio'?"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_an_added_key_unknown_to_its_typed_group_is_refused_with_a_suggestion(name: str, tmp_path) -> None:
    args, says, hint = CASES[name]
    got = run_cli(["+experiment=tiny", *args, f"hydra.run.dir={tmp_path / 'run'}"])
    assert got.code == 2
    assert says in got.error_line and got.error_line.endswith(hint), got.error_line
    assert not (tmp_path / "run").exists()


def test_an_added_key_a_typed_group_has_is_still_refused_as_existing(tmp_path) -> None:
    got = run_cli(["+experiment=tiny", "+slam.mapping_iters=5", f"hydra.run.dir={tmp_path / 'run'}"])
    assert got.code == 2 and "without '+'" in got.error_line, got.error_line
