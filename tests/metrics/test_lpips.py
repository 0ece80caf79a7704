"""LPIPS loader and forward pass, on a seeded random AlexNet written in torchvision's format.

Random backbone weights here only exercise the code path; the production path refuses to run
without a real checkpoint (``from_weights`` returns None).
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

from bench.errors import MetricError
from bench.metrics import lpips as lpips_mod
from bench.metrics.lpips import LPIPS


def _write_checkpoint(path: Path, seed: int = 0) -> Path:
    """A torchvision-format AlexNet state dict (features + classifier keys) with random weights."""
    torch.manual_seed(seed)
    features = lpips_mod._alexnet_features()
    state = {f"features.{k}": v for k, v in features.state_dict().items()}
    state["classifier.1.weight"] = torch.zeros(4, 9216)  # present in real files; must be ignored
    torch.save(state, path)
    return path


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> LPIPS:
    ckpt = _write_checkpoint(tmp_path_factory.mktemp("lpips") / "alexnet-owt-7be5be79.pth")
    m = LPIPS.from_weights(str(ckpt))
    assert m is not None
    return m


def _image(seed: int, h: int = 64, w: int = 64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(h, w, 3, generator=g)  # [H, W, 3]


def _noisy(img: torch.Tensor, sigma: float, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (img + sigma * torch.randn(img.shape, generator=g)).clamp(0, 1)


def test_identical_is_zero(model: LPIPS) -> None:
    img = _image(0)
    assert model(img, img) == 0.0


def test_symmetric(model: LPIPS) -> None:
    a, b = _image(1), _noisy(_image(1), 0.1, seed=2)
    assert model(a, b) == pytest.approx(model(b, a), rel=1e-6)


def test_grows_with_distortion(model: LPIPS) -> None:
    img = _image(3)
    low, high = model(img, _noisy(img, 0.05, seed=4)), model(img, _noisy(img, 0.2, seed=4))
    assert 0.0 < low < high


def test_matches_torchmetrics_reference(model: LPIPS, monkeypatch: pytest.MonkeyPatch) -> None:
    """Same backbone and heads in torchmetrics' own ``_LPIPS`` give the same number.

    torchvision cannot be imported here, so torchmetrics' backbone factory is pointed at our
    ``features`` stack (same indices); everything after it is torchmetrics' code.
    """
    from torchmetrics.functional.image import lpips as tm_lpips

    monkeypatch.setattr(tm_lpips, "_get_tv_model_features", lambda net, pretrained=False: model.features)
    ref = tm_lpips._LPIPS(pretrained=True, net="alex")
    a, b = _image(5, 70, 90), _noisy(_image(5, 70, 90), 0.1, seed=6)
    expected = ref(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None], normalize=True).item()
    assert model(a, b) == pytest.approx(expected, rel=1e-5)


def test_batch_distance(model: LPIPS) -> None:
    a = torch.stack([_image(7), _image(8)])  # [2, H, W, 3]
    b = torch.stack([_noisy(a[0], 0.1, 9), a[1]])
    d = model.distance(a, b)
    assert d.shape == (2,) and d[1] == 0.0
    assert float(d[0]) == pytest.approx(model(a[0], b[0]), rel=1e-5)


def test_missing_weights_return_none_with_one_notice(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    caplog.set_level(logging.INFO, logger="bench.metrics.lpips")
    assert LPIPS.from_weights(str(tmp_path / "absent.pth")) is None
    monkeypatch.setenv("POCKETBENCH_ALEXNET_WEIGHTS", str(tmp_path / "env.pth"))
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    assert LPIPS.from_weights(None) is None
    records = [r for r in caplog.records if r.name == "bench.metrics.lpips"]
    assert len(records) == 2  # one line per call
    assert str(tmp_path / "absent.pth") in records[0].getMessage()
    default_msg = records[1].getMessage()
    assert str(tmp_path / "env.pth") in default_msg
    assert str(tmp_path / "hub" / "checkpoints" / "alexnet-owt-7be5be79.pth") in default_msg
    assert all("\n" not in r.getMessage() for r in records)
    assert all("eval.lpips_weights=PATH" in r.getMessage() for r in records)  # names the setting that fixes it


def test_wrong_keys_raise_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pth"
    torch.save({"conv1.weight": torch.zeros(64, 3, 11, 11)}, bad)
    with pytest.raises(MetricError, match="lacks 'features.0.weight'") as err:
        LPIPS.from_weights(str(bad))
    assert "\n" not in str(err.value)


def test_wrong_shape_and_garbage_file(tmp_path: Path) -> None:
    ckpt = _write_checkpoint(tmp_path / "a.pth")
    state = torch.load(ckpt)
    state["features.3.weight"] = torch.zeros(10, 64, 5, 5)
    torch.save(state, ckpt)
    with pytest.raises(MetricError, match=r"'features.3.weight' expected shape \[192, 64, 5, 5\], found"):
        LPIPS.from_weights(str(ckpt))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(MetricError, match="cannot load alexnet checkpoint") as err:
        LPIPS.from_weights(str(junk))
    assert "\n" not in str(err.value)


def test_rejects_out_of_range(model: LPIPS) -> None:
    img = _image(0)
    with pytest.raises(MetricError, match=r"\[0, 1\]"):
        model(img * 2, img)


def test_rejects_too_small(model: LPIPS) -> None:
    img = _image(0, 30, 40)
    with pytest.raises(MetricError, match="at least 31x31"):
        model(img, img)
