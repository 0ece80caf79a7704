"""MaskGaussian: a learnable keep/drop mask per Gaussian, sampled with straight-through Gumbel-softmax.

Each Gaussian carries one logit l_i, the log-odds of "keep" (the 2-class keep/drop logits are
[l_i, 0]; MaskGaussian initialises its two scores to [10, 1], i.e. l = 9). During mapping the
renderer multiplies opacity by a sampled hard mask in {0, 1} whose gradient is the soft sample's,
so the logits learn from the rendering loss plus a sparsity term on the mean keep probability.

Which Gaussians are masked (``select``):
- ``ratio`` (default): at each keyframe the lowest-logit (1 - keep_ratio) of the candidates are
  masked, the rest unmasked. The Pocket-SLAM paper states its MaskGaussian baseline used the same
  pruning ratio as every method. Learning alone cannot do it here: a logit starting at 9 with
  Adam steps of 0.01 needs ~900 consistent steps to flip, and a keyframe gets 100 with fresh moments.
- ``learned``: masked iff p_keep = sigmoid(l_i) <= 0.5 (MaskGaussian's own rule); ignores the ratio.

Masked Gaussians do not render. Deletion is deferred: a masked Gaussian stays in memory (and in
the optimizer) and is removed once it has ended ``masked_keyframes`` consecutive keyframes masked
(1 = removed at once, like the other strategies). The paper attributes MaskGaussian's weak memory
savings to this deferral.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import (
    GaussianMap,
    MappingContext,
    ParamSpec,
    PruneContext,
    Strategy,
    setting,
    top_k_keep,
)

SELECT_MODES: tuple[str, ...] = ("ratio", "learned")

PARAM_LOGITS = "mask_logits"  # [N] log-odds of keep, owned and optimised by the core
STATE_MASKED_RUN = "mask_masked_keyframes"  # [N] consecutive keyframes the Gaussian has ended masked; > 0 = masked


@dataclass
class MaskPruning(Strategy):
    """Per-Gaussian masks at the shared ratio (or learned); delete after M consecutive masked keyframes."""

    description: ClassVar[str] = "MaskGaussian: masks at the shared ratio ranked by learned logits, deferred deletion"

    # ratio: mask (1 - keep_ratio) of the candidates by logit | learned: sigmoid(l) <= 0.5
    select: str = setting("ratio", "str", choices=SELECT_MODES)

    # Gumbel-softmax temperature (MaskGaussian uses torch's default, 1)
    gumbel_tau: float = setting(1.0, "float", lo=0.0, lo_open=True)
    # lambda_m on mean keep probability (MaskGaussian's lambda_mask)
    sparsity_weight: float = setting(5e-4, "float", lo=0.0)
    mask_lr: float = setting(0.01, "float", lo=0.0, lo_open=True)  # Adam step on the logits (MaskGaussian's mask_lr)
    init_keep_logit: float = 9.0  # log-odds of keep for new Gaussians (MaskGaussian's [10, 1] init)
    # M: delete once masked at this many consecutive keyframes (pocketbench choice)
    masked_keyframes: int = setting(5, "int", lo=1)
    seed: int = setting(0, "int")  # seeds the Gumbel noise, so runs are reproducible

    def __post_init__(self) -> None:
        super().__post_init__()  # each field's own rule
        self._generators: dict[torch.device, torch.Generator] = {}  # not a field: runtime state, one per device

    # ------------------------------------------------------------------ contract
    def extra_params(self) -> dict[str, ParamSpec]:
        return {PARAM_LOGITS: ParamSpec(init=self.init_keep_logit, lr=self.mask_lr)}

    def state_spec(self) -> dict[str, torch.dtype]:
        return {STATE_MASKED_RUN: torch.int32}

    def render_mask(self, ctx: MappingContext) -> torch.Tensor:
        logits = ctx.gaussians.params[PARAM_LOGITS]  # [N]
        if self.select == "learned":
            return self.sample(logits) if ctx.training else self.hard_mask(logits).to(logits.dtype)
        shown = (ctx.state[STATE_MASKED_RUN] == 0).to(logits.dtype)  # [N]
        return self.sample(logits) * shown if ctx.training else shown

    def masked_count(self, gaussians: GaussianMap, state: dict[str, torch.Tensor]) -> int:
        if self.select == "learned":
            return int((~self.hard_mask(gaussians.params[PARAM_LOGITS])).sum())
        return int((state[STATE_MASKED_RUN] > 0).sum())

    def mapping_loss(self, ctx: MappingContext) -> torch.Tensor | None:
        logits = ctx.gaussians.params[PARAM_LOGITS]  # [N]
        if not ctx.training or logits.numel() == 0 or self.sparsity_weight == 0:
            return None
        return self.sparsity_weight * torch.sigmoid(logits).mean()

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        logits = ctx.gaussians.params[PARAM_LOGITS].detach()  # [N]
        run = ctx.state[STATE_MASKED_RUN]  # [N]
        if self.select == "learned":
            masked = ~self.hard_mask(logits)  # [N]
        else:
            # candidates are re-ranked at every keyframe; a masked Gaussian out of view stays masked
            keep = top_k_keep(logits, ctx.candidates, ctx.n_target)  # [N] non-candidates included
            masked = (ctx.candidates & ~keep) | (~ctx.candidates & (run > 0))
        masked &= ~ctx.is_new
        run.copy_(torch.where(masked, run + 1, torch.zeros_like(run)))  # unmasked -> the count restarts
        return run < self.masked_keyframes

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def hard_mask(logits: torch.Tensor) -> torch.Tensor:
        """[N] bool: kept iff p_keep = sigmoid(l) > 0.5, i.e. l > 0."""
        return logits.detach() > 0

    def _generator(self, device: torch.device) -> torch.Generator:
        gen = self._generators.get(device)
        if gen is None:
            gen = torch.Generator(device=device)
            gen.manual_seed(self.seed)
            self._generators[device] = gen
        return gen

    def sample(self, logits: torch.Tensor) -> torch.Tensor:
        """[N] straight-through Gumbel-softmax keep sample: exactly 0/1 forward, soft gradient backward."""
        two = torch.stack([logits, torch.zeros_like(logits)], -1)  # [N, 2] (keep, drop) logits
        u = torch.rand(two.shape, generator=self._generator(logits.device), device=logits.device, dtype=logits.dtype)
        tiny = torch.finfo(logits.dtype).tiny
        gumbel = -torch.log((-torch.log(u.clamp_min(tiny))).clamp_min(tiny))  # [N, 2] Gumbel(0, 1)
        soft = torch.softmax((two + gumbel) / self.gumbel_tau, -1)[:, 0]  # [N] relaxed keep
        hard = (two[:, 0] + gumbel[:, 0] > gumbel[:, 1]).to(logits.dtype).detach()  # [N] argmax == keep
        return hard + (soft - soft.detach())  # the added term is exactly 0 forward, so values stay in {0, 1}
