"""A uniformly random subset: the chance baseline every criterion is read against.

At the same N_tar as a criterion, ``random`` keeps ``n_target`` of the candidates drawn uniformly without
replacement. A criterion that does not beat it on accuracy at the same count ranks Gaussians no better
than chance (SafeguardGS's harness keeps such a baseline for the same reason). The draw is seeded by the
run's seed and the keyframe index, so the same config and seed keep the same Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, Strategy, top_k_keep


def chance_score(ctx: PruneContext) -> torch.Tensor:
    """[N] iid uniform scores on ctx's device, drawn from the run's seed and the keyframe index: the top k of
    any subset of them is a uniform draw of k from that subset."""
    # one generator per prune call on the CPU, so the draw does not depend on the device or on earlier calls
    gen = torch.Generator(device="cpu").manual_seed(ctx.seed * 1_000_003 + ctx.keyframe_index)
    return torch.rand(len(ctx.gaussians), generator=gen).to(ctx.candidates.device)


@dataclass
class RandomPruning(Strategy):
    """Keep N_tar (ctx.n_target) candidates drawn uniformly at random, without replacement."""

    description: ClassVar[str] = "chance baseline: a uniformly random subset of the candidates at the same N_tar"

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        return top_k_keep(chance_score(ctx), ctx.candidates, ctx.n_target)
