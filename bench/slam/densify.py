"""The densification budget and cap (``slam.densify.*``): how many seeds a keyframe may add, which of the
candidate pixels become seeds when fewer fit, and which Gaussians leave the map to make room at the cap.

Deterministic throughout: the ``need`` order and the cap's ranking are sorts with fixed tie-breaks, and the
``random`` order draws from the run's densification generator (checkpointed with the rest of the run).
"""

from __future__ import annotations

import numpy as np
import torch

from bench.slam.config import DensifyConfig


def map_cap(dcfg: DensifyConfig, kf_idx: int, n_pixels: int) -> int | None:
    """The most Gaussians the map may hold after keyframe ``kf_idx``'s seeds (0-based): ``slam.densify.cap``,
    the rule ``cap_per_mpix_kf`` x megapixels x (``kf_idx`` + 1) for an image of ``n_pixels`` (never below
    ``cap_floor_per_px`` x ``n_pixels`` where that is set), or the lower of the two; None when neither is set.
    The rule fixes the cap before the runs from the image size and the keyframes so far, where a fixed ``cap`` is a
    count someone chose (reports/memory/README.md, "The caps")."""
    caps = [] if dcfg.cap is None else [dcfg.cap]
    if dcfg.cap_per_mpix_kf is not None:
        rule = int(dcfg.cap_per_mpix_kf * n_pixels / 1e6 * (kf_idx + 1))
        floor = 0 if dcfg.cap_floor_per_px is None else int(dcfg.cap_floor_per_px * n_pixels)
        caps.append(max(1, rule, floor))
    return min(caps) if caps else None


def taming_target(kf_idx: int, start: int, final: int, steps: int) -> int:
    """The map's target size after keyframe ``kf_idx``'s densification on Taming 3DGS's budget curve.

    Taming 3DGS, ``utils/taming_utils.py:get_count_array`` (humansensinglab/taming-3dgs, commit bc5e576),
    Eq. (2): a quadratic from ``start`` with twice the linear slope at the start and zero slope at ``steps``,
    ``int(a x^2 + b x + c)`` with ``b = 2 (final - start) / steps``, ``a = (final - start - b steps) / steps^2``,
    ``c = start``. Their x counts densification intervals of training iterations; here it is the keyframe
    index, and beyond ``steps`` the target stays at ``final`` (their curve has no step past its end).
    """
    if kf_idx >= steps:
        return final
    b = 2 * (final - start) / steps
    a = (final - start - b * steps) / (steps * steps)
    return int(a * kf_idx**2 + b * kf_idx + start)


def seed_budget(cfg: DensifyConfig, kf_idx: int, n_map: int, start: int | None) -> int | None:
    """How many seeds keyframe ``kf_idx`` may add to a map of ``n_map`` Gaussians; None = no budget.

    ``start`` is the map's size after keyframe 0 (the curve's start, as Taming starts from the SfM points);
    keyframe 0 itself is not bounded by the taming curve, only by the cap.
    """
    if cfg.budget == "constant":
        assert cfg.per_keyframe is not None  # DensifyConfig requires it with budget=constant
        return cfg.per_keyframe
    if cfg.budget == "taming":
        if start is None:
            return None
        assert cfg.final_count is not None and cfg.final_keyframe is not None  # ... and these with taming
        return max(taming_target(kf_idx, start, cfg.final_count, cfg.final_keyframe) - n_map, 0)
    return None


def pick_seeds(
    sel: torch.Tensor, k: int, order: str, deficit: torch.Tensor, err: torch.Tensor, rng: np.random.Generator
) -> torch.Tensor:
    """[H, W] bool: ``k`` of the candidate pixels ``sel`` [H, W] (all of them if they are ``k`` or fewer).

    ``random``: a uniform sample without replacement, ``rng.permutation`` of the candidates in row-major
    order (drawn only when the budget binds, so an unbound run draws as today's). ``need``: the largest
    ``deficit`` [H, W] (1 - rendered silhouette) first, then the largest ``err`` [H, W] (depth error), then
    the lower row-major pixel index. The seeds keep their row-major order either way.
    """
    idx = sel.flatten().nonzero().flatten()  # [M] ascending pixel index
    if idx.numel() <= k:
        return sel
    if order == "random":
        chosen = idx[torch.from_numpy(np.sort(rng.permutation(idx.numel())[:k])).to(idx.device)]
    else:
        for key in (err.flatten(), deficit.flatten()):  # stable sorts, least significant key first
            idx = idx[torch.sort(key[idx], descending=True, stable=True).indices]
        chosen = idx[:k]
    out = torch.zeros(sel.numel(), dtype=torch.bool, device=sel.device)
    out[chosen] = True
    return out.view_as(sel)


def cap_keep(score: torch.Tensor, n_keep: int) -> torch.Tensor:
    """[N] bool: the ``n_keep`` highest of ``score`` [N]; ties keep the lower index (the older Gaussian), as
    the criteria's equal-removal rule does (a stable descending sort)."""
    keep = torch.zeros_like(score, dtype=torch.bool)
    if n_keep > 0:
        keep[torch.sort(score, descending=True, stable=True).indices[:n_keep]] = True
    return keep
