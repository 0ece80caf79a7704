"""GaussianMap.remove: the single removal path keeps Adam moments and state aligned."""

from __future__ import annotations

import torch

from bench.slam.gaussians import GaussianMap, ParamSpec


def make_map(n: int = 6, adam_fused: bool = False) -> GaussianMap:
    g = GaussianMap(
        torch.device("cpu"),
        extra={"mask_logits": ParamSpec(init=2.0, lr=0.1)},
        state_dtypes={"score": torch.float32},
        adam_fused=adam_fused,
    )
    ar = torch.arange(n, dtype=torch.float32)
    g.add(
        {
            "means": ar[:, None].repeat(1, 3),
            "log_scales": ar[:, None].repeat(1, 3),
            "quats": torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
            "opacity_logits": ar,
            "colors": ar[:, None].repeat(1, 3),
        },
        keyframe=0,
    )
    g.state["score"] += ar
    return g


def step(g: GaussianMap) -> None:
    g.optimizer.zero_grad()
    loss = sum(
        (p * torch.arange(len(g), dtype=torch.float32).reshape(-1, *[1] * (p.dim() - 1))).sum()
        for p in g.params.values()
    )
    loss.backward()
    g.optimizer.step()


def test_remove_slices_params_moments_and_state_together():
    g = make_map()
    step(g)
    before = {k: (p.detach().clone(), g.optimizer.state[p]["exp_avg"].clone()) for k, p in g.params.items()}
    keep = torch.tensor([True, False, True, True, False, True])
    assert g.remove(keep) == 2
    assert len(g) == 4
    for k, p in g.params.items():
        torch.testing.assert_close(p.detach(), before[k][0][keep])
        st = g.optimizer.state[p]
        torch.testing.assert_close(st["exp_avg"], before[k][1][keep])
        assert st["exp_avg_sq"].shape == p.shape
        assert any(gp is p for grp in g.optimizer.param_groups for gp in grp["params"])
    torch.testing.assert_close(g.state["score"], torch.tensor([0.0, 2, 3, 5]))
    assert g.birth_kf.tolist() == [0, 0, 0, 0]
    step(g)  # the optimizer still works on the sliced tensors


def test_add_pads_moments_and_state_with_zeros_and_extras_with_init():
    g = make_map(3)
    step(g)
    g.add(
        {
            "means": torch.zeros(2, 3),
            "log_scales": torch.zeros(2, 3),
            "quats": torch.zeros(2, 4),
            "opacity_logits": torch.zeros(2),
            "colors": torch.zeros(2, 3),
        },
        keyframe=4,
    )
    assert len(g) == 5
    assert g.birth_kf.tolist() == [0, 0, 0, 4, 4]
    torch.testing.assert_close(g.params["mask_logits"].detach()[3:], torch.full((2,), 2.0))
    for p in g.params.values():
        assert (g.optimizer.state[p]["exp_avg"][3:] == 0).all()
    assert g.state["score"][3:].tolist() == [0.0, 0.0]


def test_state_bytes_counts_params_grads_moments_and_state():
    g = make_map(4)
    n_floats = 4 * (3 + 3 + 4 + 1 + 3 + 1)  # params incl. mask logits
    expected = n_floats * 4 + 4 * 8 + 4 * 4  # + birth_kf int64 + score float32
    assert g.state_bytes() == expected
    step(g)
    assert g.state_bytes() == expected + 3 * n_floats * 4  # + grads + exp_avg + exp_avg_sq


def test_fused_adam_steps_as_the_per_op_adam_to_float_rounding_and_survives_remove_and_add():
    """``slam.adam_fused``: the same update as torch's per-op Adam (differences at float rounding only),
    through a remove and an add that carry the moments."""
    maps = {}
    for fused in (False, True):
        g = make_map(40, adam_fused=fused)
        for _ in range(3):
            step(g)
        g.remove(torch.arange(40) % 3 != 0)
        step(g)
        maps[fused] = g
    assert maps[True].optimizer.defaults["fused"] and not maps[False].optimizer.defaults["fused"]
    for k, p in maps[False].params.items():
        q = maps[True].params[k]
        torch.testing.assert_close(q.detach(), p.detach(), rtol=1e-6, atol=1e-6)
        torch.testing.assert_close(
            maps[True].optimizer.state[q]["exp_avg_sq"], maps[False].optimizer.state[p]["exp_avg_sq"]
        )


def test_the_map_builds_fused_adam_when_asked():
    assert GaussianMap(torch.device("cpu"), adam_fused=True).optimizer.defaults["fused"]
    assert not GaussianMap(torch.device("cpu")).optimizer.defaults["fused"]
