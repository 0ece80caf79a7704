"""LPIPS (AlexNet) without downloads and without torchvision.

torchmetrics' own LPIPS builds its backbone through torchvision, which cannot be imported here,
and would download ImageNet weights. This module re-implements the same network: an AlexNet
``features`` stack with torchvision's exact layer indices (so a standard torchvision checkpoint,
``alexnet-owt-7be5be79.pth``, with keys ``features.N.weight``/``bias``, loads as is) plus the
LPIPS linear heads that torchmetrics ships inside its package (``lpips_models/alex.pth``). The
forward pass mirrors torchmetrics' ``_LPIPS`` (v0.1, ``normalize=True``): [0, 1] -> [-1, 1],
ScalingLayer shift/scale, relu1..relu5 taps, per-pixel channel unit-normalisation (eps 1e-8),
squared difference, 1x1 linear heads, spatial mean, sum over the five layers.
tests/metrics/test_lpips.py checks it against torchmetrics' code with identical weights.

If no backbone checkpoint is found, :meth:`LPIPS.from_weights` returns ``None`` and logs one
line saying where it looked: a number from random weights is never produced.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch
from torch import nn

from bench.errors import MetricError

logger = logging.getLogger(__name__)

ALEXNET_CHECKPOINT = "alexnet-owt-7be5be79.pth"  # torchvision's IMAGENET1K_V1 file name
LPIPS_CHANNELS = (64, 192, 384, 256, 256)  # relu1..relu5 widths
# torchvision alexnet().features indices that hold parameters: (index, out, in, kernel)
_CONV_LAYOUT = ((0, 64, 3, 11), (3, 192, 64, 5), (6, 384, 192, 3), (8, 256, 384, 3), (10, 256, 256, 3))
_TAP_AFTER = (1, 4, 7, 9, 11)  # outputs of features[i] that LPIPS compares (the ReLUs)
_SHIFT = (-0.030, -0.088, -0.188)  # LPIPS ScalingLayer
_SCALE = (0.458, 0.448, 0.450)
MIN_SIDE_PX = 31  # smallest input AlexNet's two 3x3/2 pools accept


def _alexnet_features() -> nn.Sequential:
    """Same modules and indices as ``torchvision.models.alexnet().features`` (minus the last pool)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),  # 0
        nn.ReLU(),  # 1
        nn.MaxPool2d(kernel_size=3, stride=2),  # 2
        nn.Conv2d(64, 192, kernel_size=5, padding=2),  # 3
        nn.ReLU(),  # 4
        nn.MaxPool2d(kernel_size=3, stride=2),  # 5
        nn.Conv2d(192, 384, kernel_size=3, padding=1),  # 6
        nn.ReLU(),  # 7
        nn.Conv2d(384, 256, kernel_size=3, padding=1),  # 8
        nn.ReLU(),  # 9
        nn.Conv2d(256, 256, kernel_size=3, padding=1),  # 10
        nn.ReLU(),  # 11
    )


def torchmetrics_linear_weights_path() -> Path:
    """Where torchmetrics keeps the LPIPS v0.1 AlexNet linear heads."""
    import torchmetrics.functional.image as tm_image

    return Path(tm_image.__file__).resolve().parent / "lpips_models" / "alex.pth"


def default_checkpoint_paths() -> list[Path]:
    """Candidate backbone checkpoints: ``$POCKETBENCH_ALEXNET_WEIGHTS``, then the torch hub cache."""
    paths = []
    env = os.environ.get("POCKETBENCH_ALEXNET_WEIGHTS")
    if env:
        paths.append(Path(env).expanduser())
    paths.append(Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_CHECKPOINT)
    return paths


def _load_state(path: Path, what: str) -> dict[str, torch.Tensor]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle/zip errors of many kinds; the message is what matters
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise MetricError(f"cannot load {what} {path}: expected a torch state dict, found error: {msg}") from None
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise MetricError(f"{what} {path}: expected a state dict, found {type(state).__name__}")
    return state


class LPIPS:
    """Learned perceptual distance (AlexNet, LPIPS v0.1); 0 = identical, larger = more different."""

    def __init__(self, features: nn.Sequential, lins: nn.ModuleList, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        self.features = features.eval().to(self.device)
        self.lins = lins.eval().to(self.device)
        for p in [*self.features.parameters(), *self.lins.parameters()]:
            p.requires_grad_(False)
        self.shift = torch.tensor(_SHIFT, device=self.device).view(1, 3, 1, 1)
        self.scale = torch.tensor(_SCALE, device=self.device).view(1, 3, 1, 1)

    @classmethod
    def from_weights(cls, path: str | Path | None = None, device: torch.device | str = "cpu") -> LPIPS | None:
        """Load a torchvision AlexNet checkpoint (``path`` or the default places) and torchmetrics' heads.

        Returns ``None`` (with one logged notice) when no checkpoint exists; raises ``MetricError``
        when a file exists but does not hold the expected tensors.
        """
        candidates = [Path(path).expanduser()] if path else default_checkpoint_paths()
        found = next((p for p in candidates if p.is_file()), None)
        if found is None:
            logger.warning(
                "lpips disabled: no alexnet checkpoint found, looked at %s; set eval.lpips_weights=PATH "
                "(or $POCKETBENCH_ALEXNET_WEIGHTS) to alexnet-owt-7be5be79.pth, or eval.lpips=false to skip it",
                ", ".join(map(str, candidates)),
            )
            return None
        lin_path = torchmetrics_linear_weights_path()
        if not lin_path.is_file():
            logger.warning("lpips disabled: torchmetrics lpips linear weights not found at %s", lin_path)
            return None

        backbone_state = _load_state(found, "alexnet checkpoint")
        features = _alexnet_features()
        fstate = {}
        for idx, c_out, c_in, k in _CONV_LAYOUT:
            for name, shape in (("weight", (c_out, c_in, k, k)), ("bias", (c_out,))):
                key = f"features.{idx}.{name}"
                if key not in backbone_state:
                    keys = list(backbone_state)
                    head = ", ".join(keys[:4]) + (", ..." if len(keys) > 4 else "")
                    raise MetricError(
                        f"alexnet checkpoint {found} lacks '{key}': expected torchvision alexnet keys, "
                        f"found {len(keys)} keys ({head or 'none'})"
                    )
                value = backbone_state[key]
                if tuple(value.shape) != shape:
                    raise MetricError(
                        f"alexnet checkpoint {found}: '{key}' expected shape {list(shape)}, found {list(value.shape)}"
                    )
                fstate[f"{idx}.{name}"] = value.float()
        features.load_state_dict(fstate, strict=True)

        lin_state = _load_state(lin_path, "lpips linear weights")
        convs = [nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in LPIPS_CHANNELS]
        for i, (c, conv) in enumerate(zip(LPIPS_CHANNELS, convs, strict=True)):
            key = f"lin{i}.model.1.weight"  # torchmetrics names (dropout at .0, conv at .1)
            if key not in lin_state or tuple(lin_state[key].shape) != (1, c, 1, 1):
                raise MetricError(f"lpips linear weights {lin_path}: expected '{key}' of shape [1, {c}, 1, 1]")
            conv.weight.data.copy_(lin_state[key].float())
        lins = nn.ModuleList(convs)
        logger.info("lpips: alexnet backbone from %s, linear heads from %s", found, lin_path)
        return cls(features, lins, device)

    def to(self, device: torch.device | str) -> LPIPS:
        """The same network on ``device`` (a model loaded on CPU at validation, used where the run renders)."""
        return self if torch.device(device) == self.device else LPIPS(self.features, self.lins, device)

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in _TAP_AFTER:
                taps.append(x)
        return taps

    @torch.no_grad()
    def distance(self, preds: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """Batched LPIPS: ``[B, H, W, 3]`` in [0, 1] -> ``[B]``."""
        if preds.shape != targets.shape or preds.ndim != 4 or preds.shape[-1] != 3:
            raise MetricError(
                f"lpips inputs must both be [b, h, w, 3]: found {list(preds.shape)} and {list(targets.shape)}"
            )
        if min(preds.shape[1:3]) < MIN_SIDE_PX:
            raise MetricError(
                f"lpips needs images of at least {MIN_SIDE_PX}x{MIN_SIDE_PX} px: found {list(preds.shape[1:3])}"
            )
        lo = min(float(preds.min()), float(targets.min()))
        hi = max(float(preds.max()), float(targets.max()))
        if not (lo >= 0.0 and hi <= 1.0):  # also catches nan
            raise MetricError(f"lpips inputs must lie in [0, 1]: found range [{lo:.4g}, {hi:.4g}]")
        x0 = preds.to(self.device, torch.float32).permute(0, 3, 1, 2)  # [B, 3, H, W]
        x1 = targets.to(self.device, torch.float32).permute(0, 3, 1, 2)  # [B, 3, H, W]
        x0 = ((2 * x0 - 1) - self.shift) / self.scale
        x1 = ((2 * x1 - 1) - self.shift) / self.scale
        total = torch.zeros(x0.shape[0], device=self.device)  # [B]
        for lin, f0, f1 in zip(self.lins, self._taps(x0), self._taps(x1), strict=True):
            f0 = f0 / torch.sqrt(1e-8 + (f0**2).sum(dim=1, keepdim=True))  # unit length per pixel
            f1 = f1 / torch.sqrt(1e-8 + (f1**2).sum(dim=1, keepdim=True))
            total += lin((f0 - f1) ** 2).mean(dim=(1, 2, 3))  # [B]
        return total

    def __call__(self, pred: torch.Tensor, target: torch.Tensor) -> float:
        """LPIPS of one ``[H, W, 3]`` image pair in [0, 1]."""
        if pred.ndim != 3:
            raise MetricError(f"lpips expects one [h, w, 3] image: found {list(pred.shape)}")
        return float(self.distance(pred[None], target[None])[0])
