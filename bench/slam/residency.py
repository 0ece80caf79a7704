"""Map residency (``slam.residency.*``): Gaussians far from the camera wait on disk, not in memory.

Why: the street behind the car stays in memory although it is out of view (``reports/scale``), and no
pruning criterion reaches it. VINGS-Mono (``scripts/storage/storage_manage.py``, ``StorageManager.run``)
measures, every few frames, the distance from the current camera to each keyframe's camera; the
Gaussians anchored at a keyframe farther than a threshold move off the GPU (``gpu2cpu``), those of a
keyframe that is near again come back (``cpu2gpu``), restore before evict. Gaussian-SLAM
(``src/entities/gaussian_slam.py``, ``start_new_submap``) writes a finished submap to a file in the run
dir. Policy ``distance`` is VINGS-Mono's rule with Gaussian-SLAM's destination: each Gaussian's anchor is
the keyframe that seeded it (``GaussianMap.birth_kf``), and an anchor's Gaussians go to one file
``map_store/kfNNNNNN.pt`` in the run dir, with everything per-Gaussian the core keeps (parameters, Adam
moments, state). Unlike VINGS-Mono, which rebuilds its optimiser on the way back, the moments return.

Order, so that a run is repeatable: an anchor's Gaussians are written in map order and come back
appended after the live map, anchors in ascending order, each in its written order. While on disk a
Gaussian is in no render: tracking, mapping and pruning see the live map only. A milestone
(``eval.at_frames``) scores a copy of the whole map (``whole_map``), the live map untouched, so that it
scores what the run has made so far, as the end of a run does; the evaluation at the end of a run brings every
Gaussian back first (``System.restore_all``).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bench.config.settings import check_rules, setting
from bench.errors import BenchError, ConfigError
from bench.slam.gaussians import GaussianMap

POLICIES = ("off", "distance")
STORE_DIR = "map_store"  # in the run dir


class ResidencyError(BenchError):
    """The map store on disk does not hold what the run wrote there (a file removed or cut short)."""


@dataclass
class ResidencyConfig:
    """``slam.residency.NAME``: which Gaussians wait on disk. ``off`` keeps the whole map in memory (today)."""

    # off: all in memory; distance: an anchor keyframe whose camera centre is farther than distance_m from
    # the current camera has its Gaussians on disk (VINGS-Mono's rule; it uses 60-120 m)
    policy: str = setting("off", "str", choices=POLICIES)
    distance_m: float = setting(60.0, "float", lo=0.0, lo_open=True)
    # an anchor on disk comes back within distance_m - hysteresis_m; 0 = the same distance both ways, as
    # VINGS-Mono. Above 0 an anchor near the threshold does not go back and forth at every check
    hysteresis_m: float = setting(0.0, "float", lo=0.0)
    check_every: int = setting(1, "int", lo=1)  # keyframes between checks (VINGS-Mono: every 10 frames)
    # a Gaussian of a far anchor whose centre projects into the current image stays in memory; false = the
    # anchor's Gaussians all go, in view or not (VINGS-Mono). Why: an anchor seeds its view to the depth
    # limit, so the far end of the street leaves with a keyframe 30 m behind although it is straight ahead,
    # and the next keyframe seeds it again; on the way back both copies are in the map
    keep_in_view: bool = setting(True, "bool")

    def __post_init__(self) -> None:
        check_rules(self, "slam.residency.")
        if self.hysteresis_m >= self.distance_m:
            raise ConfigError(
                f"slam.residency.hysteresis_m: expected less than distance_m={self.distance_m:g}, "
                f"found {self.hysteresis_m:g}"
            )


def camera_centre(w2c: torch.Tensor) -> torch.Tensor:
    """World position [3] (float64, CPU) of the camera of world-to-camera ``w2c`` [4, 4]."""
    m = w2c.detach().double().cpu()
    return -m[:3, :3].T @ m[:3, 3]


def in_image(means: torch.Tensor, w2c: torch.Tensor, K: torch.Tensor, hw: tuple[int, int]) -> torch.Tensor:
    """[N] bool: the centre of each Gaussian (``means`` [N, 3], world) is in front of the camera and
    projects inside the ``hw`` (height, width) image."""
    p = means @ w2c[:3, :3].T + w2c[:3, 3]  # [N, 3] camera frame
    z = p[:, 2]
    front = z > 1e-6
    zs = z.clamp_min(1e-6)
    u = K[0, 0] * p[:, 0] / zs + K[0, 2]
    v = K[1, 1] * p[:, 1] / zs + K[1, 2]
    return front & (u >= 0) & (u < hw[1]) & (v >= 0) & (v < hw[0])


class MapResidency:
    """The Gaussians on disk, by anchor keyframe, and the camera centre of every keyframe (the anchors).

    ``disk_bytes`` is what the store holds on disk now; ``n_evicted`` the Gaussians in it.
    """

    def __init__(self, cfg: ResidencyConfig, directory: Path | None = None) -> None:
        self.cfg = cfg
        self.dir = directory
        self.centres: list[torch.Tensor] = []  # per keyframe index, its camera centre [3] (float64)
        self.on_disk: dict[int, tuple[int, int]] = {}  # anchor keyframe -> (Gaussians, file bytes)
        self.far: set[int] = set()  # keyframes farther than distance_m at the last check

    # ------------------------------------------------------------------------------------------ where
    def use_dir(self, directory: Path) -> None:
        """Store files in ``directory`` (the run dir's ``map_store``); files a previous run left there go."""
        self.dir = directory
        if directory.is_dir():
            for path in sorted(directory.glob("kf*.pt")):
                path.unlink()

    def _path(self, anchor: int) -> Path:
        if self.dir is None:  # a System used outside a run (tests, scripts): a private folder
            self.dir = Path(tempfile.mkdtemp(prefix="pocketbench-map-store-"))
        self.dir.mkdir(parents=True, exist_ok=True)
        return self.dir / f"kf{anchor:06d}.pt"

    # ----------------------------------------------------------------------------------------- counts
    def n_evicted(self) -> int:
        return sum(n for n, _ in self.on_disk.values())

    def disk_bytes(self) -> int:
        return sum(b for _, b in self.on_disk.values())

    # ----------------------------------------------------------------------------------------- policy
    def note_keyframe(self, kf_idx: int, w2c: torch.Tensor) -> None:
        if kf_idx != len(self.centres):
            raise ValueError(f"map residency: expected keyframe {len(self.centres)}, found {kf_idx}")
        self.centres.append(camera_centre(w2c))

    def due(self, kf_idx: int) -> bool:
        return self.cfg.policy != "off" and kf_idx % self.cfg.check_every == 0

    def check(
        self, gmap: GaussianMap, w2c: torch.Tensor, K: torch.Tensor | None = None, hw: tuple[int, int] = (0, 0)
    ) -> tuple[int, int]:
        """(Gaussians brought back, Gaussians written out) at the camera ``w2c`` [4, 4] with intrinsics ``K``
        [3, 3] and image size ``hw``: first the anchors on disk that are near again come back, then the
        Gaussians of the live anchors that are far go (with ``keep_in_view``, those outside the image)."""
        dist = (torch.stack(self.centres) - camera_centre(w2c)).norm(dim=-1)  # [K] m
        near = sorted(a for a in self.on_disk if float(dist[a]) <= self.cfg.distance_m - self.cfg.hysteresis_m)
        restored = sum(self._bring_back(gmap, a) for a in near)
        anchors = torch.unique(gmap.birth_kf.cpu()).tolist()  # ascending
        self.far = {k for k in range(len(self.centres)) if float(dist[k]) > self.cfg.distance_m}
        far = [a for a in anchors if a in self.far]
        stays = None
        if far and self.cfg.keep_in_view and K is not None:
            stays = in_image(gmap.means.detach(), w2c, K, hw)
        return restored, self._write_out(gmap, far, stays)

    def resident(self, kf_idx: int) -> bool:
        """Whether mapping may draw keyframe ``kf_idx``: not farther than ``distance_m`` at the last check."""
        return kf_idx not in self.far

    def restore_all(self, gmap: GaussianMap) -> int:
        """Every Gaussian on disk back in the map (before the evaluation); the store is left empty."""
        self.far = set()
        return sum(self._bring_back(gmap, a) for a in sorted(self.on_disk))

    def whole_map(self, gmap: GaussianMap) -> GaussianMap:
        """A copy of ``gmap`` with every Gaussian on disk appended, in the order ``restore_all`` gives
        (anchors ascending): what the milestones score. Neither ``gmap`` nor the store changes, so a run
        scored at its milestones goes on exactly as one that is not."""
        whole = GaussianMap(gmap.device, gmap.lrs, gmap.extra, {k: v.dtype for k, v in gmap.state.items()})
        # the live rows without their Adam moments (the copy has no optimiser state, so extend would drop
        # them) and uncloned (extend concatenates into new tensors)
        live = {"params": {k: p.detach() for k, p in gmap.params.items()}, "moments": {}}
        whole.extend({**live, "birth_kf": gmap.birth_kf, "state": dict(gmap.state)})
        for anchor in sorted(self.on_disk):
            whole.extend(self._read(anchor))
        return whole

    def _write_out(self, gmap: GaussianMap, anchors: list[int], stays: torch.Tensor | None = None) -> int:
        """Write the Gaussians of ``anchors`` but those ``stays`` [N] bool keeps, one file per anchor
        (appended to the anchor's file where part of it is on disk already), then remove them."""
        if not anchors:
            return 0
        birth = gmap.birth_kf
        leaving = torch.isin(birth, torch.tensor(anchors, dtype=birth.dtype, device=birth.device))
        if stays is not None:
            leaving &= ~stays
        for a in anchors:
            mask = leaving & (birth == a)
            if not bool(mask.any()):
                continue
            chunk = gmap.take(mask)
            if a in self.on_disk:
                chunk = _concat(self._read(a), chunk)
            self._write(a, chunk)
        return gmap.remove(~leaving)

    def _bring_back(self, gmap: GaussianMap, anchor: int) -> int:
        chunk = self._read(anchor)
        self._path(anchor).unlink()
        del self.on_disk[anchor]
        return gmap.extend(chunk)

    def _write(self, anchor: int, chunk: dict[str, Any]) -> None:
        path = self._path(anchor)
        torch.save(chunk, path)
        self.on_disk[anchor] = (int(chunk["birth_kf"].shape[0]), path.stat().st_size)

    def _read(self, anchor: int) -> dict[str, Any]:
        path = self._path(anchor)
        try:
            chunk = torch.load(path, map_location="cpu", weights_only=True)
        except (OSError, RuntimeError) as exc:
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise ResidencyError(
                f"map residency: expected the Gaussians of keyframe {anchor} in {path}, found {first}"
            ) from None
        n = self.on_disk[anchor][0]
        if int(chunk["birth_kf"].shape[0]) != n:
            raise ResidencyError(
                f"map residency: expected {n} Gaussians in {path}, found {int(chunk['birth_kf'].shape[0])}"
            )
        return chunk

    # ------------------------------------------------------------------------------------- checkpoint
    def state_dict(self) -> dict[str, Any]:
        """The keyframes' centres and every Gaussian on disk, held in the checkpoint itself: a checkpoint
        that only pointed at the files would be wrong once a later keyframe brought them back or added to
        them (``checkpoint.prev.pt`` is one to a few keyframes older than the store)."""
        return {
            "centres": torch.stack(self.centres) if self.centres else torch.zeros(0, 3, dtype=torch.float64),
            "chunks": {str(a): self._read(a) for a in sorted(self.on_disk)},
            "far": torch.tensor(sorted(self.far), dtype=torch.long),
        }

    def load_state_dict(self, sd: dict[str, Any]) -> None:
        """Undo ``state_dict``: the store's files are written again from the checkpoint."""
        self.centres = list(sd["centres"])
        self.far = set(sd["far"].tolist())
        for a in sorted(self.on_disk):
            self._path(a).unlink(missing_ok=True)
        self.on_disk = {}
        for key, chunk in sorted(sd["chunks"].items(), key=lambda kv: int(kv[0])):
            self._write(int(key), chunk)


def _concat(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Two chunks of ``GaussianMap.take`` as one, ``a``'s rows first (moments kept where both have them)."""
    return {
        "params": {k: torch.cat([v, b["params"][k]]) for k, v in a["params"].items()},
        "moments": {k: torch.cat([v, b["moments"][k]]) for k, v in a["moments"].items() if k in b["moments"]},
        "birth_kf": torch.cat([a["birth_kf"], b["birth_kf"]]),
        "state": {k: torch.cat([v, b["state"][k]]) for k, v in a["state"].items()},
    }
