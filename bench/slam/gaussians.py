"""The Gaussian map: parameters, their optimizer, and per-Gaussian state, kept aligned.

Every per-Gaussian tensor lives here and changes length only through ``add`` and
``remove`` (gsplat's ``strategy/ops.py`` pattern), so the Adam moments, the strategy's
state and the birth keyframe can never drift out of step with the parameters.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass

import torch

from bench.config.settings import check_rules, setting


@dataclass
class LearningRates:
    """Adam learning rate per Gaussian parameter (``slam.lrs.NAME``).

    Tuned for ~100 mapping iterations per keyframe rather than 3DGS's 30k: colours and log-scales
    step faster than 3DGS's colour rate (log-scales at 3DGS's rate).
    """

    means: float = setting(1e-2, "float", lo=0.0)  # metres per Adam step; outdoor scenes span 3-120 m
    log_scales: float = setting(5e-3, "float", lo=0.0)
    quats: float = setting(1e-3, "float", lo=0.0)
    opacity_logits: float = setting(5e-2, "float", lo=0.0)
    colors: float = setting(2e-2, "float", lo=0.0)

    def __post_init__(self) -> None:
        check_rules(self, "slam.lrs.")


DEFAULT_LRS: dict[str, float] = asdict(LearningRates())


@dataclass(frozen=True)
class ParamSpec:
    """An extra per-Gaussian parameter a strategy asks the core to own (e.g. mask logits)."""

    init: float  # value for every new Gaussian
    lr: float
    dim: int = 0  # 0 -> shape [N]; k -> [N, k]


class GaussianMap:
    """Anisotropic 3D Gaussians in world coordinates.

    Parameters: ``means`` [N, 3] m, ``log_scales`` [N, 3] log m, ``quats`` [N, 4] wxyz
    (unnormalised), ``opacity_logits`` [N], ``colors`` [N, 3] RGB, plus any strategy extras.
    Non-parameter state: ``birth_kf`` [N] (keyframe index that created the Gaussian) and
    ``state`` (per-Gaussian tensors owned by the core, written by the strategy).
    """

    def __init__(
        self,
        device: torch.device,
        lrs: dict[str, float] | None = None,
        extra: dict[str, ParamSpec] | None = None,
        state_dtypes: dict[str, torch.dtype] | None = None,
        adam_fused: bool = False,
    ):
        self.device = device
        self.lrs = dict(DEFAULT_LRS if lrs is None else lrs)
        self.extra = dict(extra or {})
        shapes = {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": 0, "colors": 3}
        shapes.update({k: s.dim for k, s in self.extra.items()})
        self.lrs.update({k: s.lr for k, s in self.extra.items()})
        self.params: dict[str, torch.nn.Parameter] = {
            k: torch.nn.Parameter(torch.empty((0, d) if d else (0,), device=device)) for k, d in shapes.items()
        }
        self.birth_kf = torch.empty(0, dtype=torch.long, device=device)
        self.state: dict[str, torch.Tensor] = {
            k: torch.empty(0, dtype=dt, device=device) for k, dt in (state_dtypes or {}).items()
        }
        self.optimizer = torch.optim.Adam(
            [{"params": [p], "lr": self.lrs[k], "name": k} for k, p in self.params.items()],
            eps=1e-15,
            fused=adam_fused or None,  # None: torch's per-op default (``slam.adam_fused``)
        )

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    def __getattr__(self, name: str) -> torch.Tensor:
        params = self.__dict__.get("params")
        if params is not None and name in params:
            return params[name]
        raise AttributeError(name)

    @property
    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.params["opacity_logits"])  # [N]

    def _swap(self, fn) -> None:
        """Replace every parameter by ``fn(old)`` and carry its Adam moments with it."""
        for group in self.optimizer.param_groups:
            old = group["params"][0]
            new = torch.nn.Parameter(fn(old.detach(), 0.0))
            st = self.optimizer.state.pop(old, None)
            if st:
                for key in ("exp_avg", "exp_avg_sq"):
                    st[key] = fn(st[key], 0.0)
                self.optimizer.state[new] = st
            group["params"][0] = new
            self.params[group["name"]] = new

    def add(self, values: dict[str, torch.Tensor], keyframe: int) -> None:
        """Append Gaussians; missing extras take their spec's init, new moments and state are zero."""
        n = values["means"].shape[0]
        if n == 0:
            return
        full = dict(values)
        for k, spec in self.extra.items():
            if k not in full:
                shape = (n, spec.dim) if spec.dim else (n,)
                full[k] = torch.full(shape, spec.init, device=self.device)
        for k in self.params:
            if k not in full:
                raise KeyError(f"add() needs '{k}'")

        for group in self.optimizer.param_groups:
            name = group["name"]
            old = group["params"][0]
            new = torch.nn.Parameter(torch.cat([old.detach(), full[name].to(old.dtype)], 0))
            st = self.optimizer.state.pop(old, None)
            if st:
                for key in ("exp_avg", "exp_avg_sq"):
                    pad = torch.zeros((n, *st[key].shape[1:]), dtype=st[key].dtype, device=self.device)
                    st[key] = torch.cat([st[key], pad], 0)
                self.optimizer.state[new] = st
            group["params"][0] = new
            self.params[name] = new
        self.birth_kf = torch.cat([self.birth_kf, torch.full((n,), keyframe, dtype=torch.long, device=self.device)])
        for k, v in self.state.items():
            self.state[k] = torch.cat([v, torch.zeros((n, *v.shape[1:]), dtype=v.dtype, device=self.device)])

    def remove(self, keep: torch.Tensor) -> int:
        """The only removal path: slice params, Adam moments, birth keyframe and state by ``keep`` [N] bool."""
        if keep.dtype != torch.bool or keep.shape != (len(self),):
            raise ValueError(f"keep mask: expected bool [{len(self)}], found {keep.dtype} {list(keep.shape)}")
        removed = int((~keep).sum())
        if removed == 0:
            return 0
        self._swap(lambda t, _fill: t[keep])
        self.birth_kf = self.birth_kf[keep]
        for k, v in self.state.items():
            self.state[k] = v[keep]
        return removed

    def take(self, mask: torch.Tensor) -> dict[str, dict[str, torch.Tensor] | torch.Tensor]:
        """Copies of the ``mask`` [N] bool rows of everything per-Gaussian, in map order: params, Adam
        moments (where Adam holds them), birth keyframe and state. Nothing changes here: the caller
        removes the rows through ``remove``, the one removal path (map residency writes them to disk)."""
        moments: dict[str, torch.Tensor] = {}
        for group in self.optimizer.param_groups:
            st = self.optimizer.state.get(group["params"][0])
            if st:
                for key in ("exp_avg", "exp_avg_sq"):
                    moments[f"{group['name']}.{key}"] = st[key][mask].clone()
        return {
            "params": {k: p.detach()[mask].clone() for k, p in self.params.items()},
            "moments": moments,
            "birth_kf": self.birth_kf[mask].clone(),
            "state": {k: v[mask].clone() for k, v in self.state.items()},
        }

    def extend(self, chunk: dict) -> int:
        """Append rows that ``take`` copied, with their moments and state (map residency brings them back).

        Where Adam holds no moments now (none yet, or cleared) the chunk's are dropped: Adam starts them
        at zero for every row at its next step; where the chunk has none, its rows get zero moments as
        ``add`` gives. Adam's step count is one per parameter and stays the live map's."""
        n = int(chunk["birth_kf"].shape[0])
        if n == 0:
            return 0
        if set(chunk["params"]) != set(self.params):
            raise ValueError(f"map parameters: expected {sorted(self.params)}, found {sorted(chunk['params'])}")
        for group in self.optimizer.param_groups:
            name = group["name"]
            old = group["params"][0]
            rows = chunk["params"][name].to(device=self.device, dtype=old.dtype)
            new = torch.nn.Parameter(torch.cat([old.detach(), rows], 0), requires_grad=old.requires_grad)
            st = self.optimizer.state.pop(old, None)
            if st:
                for key in ("exp_avg", "exp_avg_sq"):
                    more = chunk["moments"].get(f"{name}.{key}")
                    if more is None:
                        more = torch.zeros((n, *st[key].shape[1:]), dtype=st[key].dtype)
                    st[key] = torch.cat([st[key], more.to(device=self.device, dtype=st[key].dtype)], 0)
                self.optimizer.state[new] = st
            group["params"][0] = new
            self.params[name] = new
        self.birth_kf = torch.cat([self.birth_kf, chunk["birth_kf"].to(self.device)])
        for k, v in self.state.items():
            self.state[k] = torch.cat([v, chunk["state"][k].to(device=self.device, dtype=v.dtype)])
        return n

    def state_bytes(self) -> int:
        """Exact bytes of Gaussian state: params, grads, Adam moments and per-Gaussian state."""
        tensors: list[torch.Tensor] = [self.birth_kf, *self.state.values()]
        for p in self.params.values():
            st = self.optimizer.state.get(p, {})
            moments = [st[k] for k in ("exp_avg", "exp_avg_sq") if k in st]
            tensors += [p, *([p.grad] if p.grad is not None else []), *moments]
        return tensor_bytes(tensors)


def tensor_bytes(tensors: Iterable[torch.Tensor]) -> int:
    """Exact payload bytes (``numel * element_size``) of the given tensors, e.g. the Gaussian state.

    Views are counted by their own extent, not their storage's; pass each tensor once.
    """
    return int(sum(t.numel() * t.element_size() for t in tensors))
