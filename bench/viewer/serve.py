"""The viser server behind ``python -m bench.view``: ``RunScene``s (``bench.viewer.scene``) as scene nodes and a
few GUI controls. viser is the optional extra ``view``; nothing in a run imports this module.

Scene nodes, per shown run (slot ``A``, and ``B`` for a second run): ``/A`` (a frame that holds the run's
offset), ``/A/map`` (the splats), ``/A/pruned`` (the centres one recorded prune removed, one colour),
``/A/traj_est`` and ``/A/traj_gt`` (line strips), ``/A/keyframes/kf_NNN`` (the keyframe frustums).
"""

from __future__ import annotations

import errno
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.errors import BenchError, ConfigError
from bench.viewer.scene import (
    RunScene,
    Splats,
    extent,
    load_snapshot,
    overview,
    pruned_points,
    read_run,
    run_label,
    side_by_side,
)

INSTALL_HINT = 'install it with pip install -e ".[view]"'
SLOTS = ("A", "B")
EST_RGB = (30, 110, 230)  # estimated trajectory
GT_RGB = (40, 40, 40)  # ground truth
PRUNED_RGB = (230, 30, 30)  # what a prune removed
KF_RGB = (240, 150, 20)  # keyframe frustums
FINAL = "final map"


def import_viser() -> Any:
    """The viser module; a ``ConfigError`` line saying how to install it where it is missing."""
    try:
        import viser
    except ImportError:
        raise ConfigError(f"the viewer needs viser, found it not installed: {INSTALL_HINT}") from None
    return viser


def check_port(host: str, port: int) -> None:
    """A ``ConfigError`` line unless ``port`` on ``host`` is free (viser itself would move to the next one)."""
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port: expected 0-65535, found {port}")
    if port == 0:
        return  # the system picks a free one
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ConfigError(f"--port: expected a free port, found {port} in use on {host}") from None
            raise ConfigError(f"--host/--port: expected an address to serve on, found {host}:{port}: {exc}") from None


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """[F, 3] points -> [F - 1, 2, 3] consecutive segments (viser's ``add_line_segments``)."""
    return np.stack([points[:-1], points[1:]], axis=1)


@dataclass
class Slot:
    """One shown run: its candidates (a sweep's runs, or just the one) and the scene nodes drawn for it."""

    name: str
    runs: list[Path]
    root: Path
    scene: RunScene
    nodes: dict[str, Any] = field(default_factory=dict)
    shown_step: int | None = None  # keyframe whose snapshot the map node shows; None: the final map


class Viewer:
    """A running viser server showing one or two runs; ``stop()`` ends it."""

    def __init__(
        self,
        slots: list[tuple[list[Path], Path, int]],
        host: str = "127.0.0.1",
        port: int = 8080,
        keyframe: int | None = None,
    ):
        """``slots``: per run shown, (its candidate run dirs, the dir they were found under, the one shown first);
        ``keyframe``: the slider's start (None: the final map)."""
        self.lock = threading.RLock()  # GUI callbacks run on viser's threads, one per client event
        self.error: BenchError | None = None  # what the last step could not read
        self.slots = [  # the runs first: a bad run dir is the first thing said, viser or not
            Slot(name, runs, root, read_run(runs[pick], run_label(runs[pick], root)))
            for name, (runs, root, pick) in zip(SLOTS, slots, strict=False)
        ]
        self.steps = self._all_steps()
        self._check_step(keyframe)
        check_port(host, port)
        viser = import_viser()
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:  # taken between the check and the bind: viser moved on
            self.server.stop()
            raise ConfigError(f"--port: expected a free port, found {port} in use on {host}")
        self.host, self.port = host, self.server.get_port()
        try:
            self.server.scene.set_up_direction("-y")  # the camera's y points down in every dataset's frames
            self._gui()
            for slot in self.slots:
                self._draw(slot)
            self._layout()
            self.show(keyframe)
        except BaseException:  # a corrupt snapshot, say: no server left running behind the error line
            self.server.stop()
            raise

    def _aim(self) -> None:
        """The camera a new page starts from (and "Reset View" returns to): every shown map in view."""
        bounds = []
        for slot in self.slots:
            lo, hi = extent(slot.scene)
            if slot.nodes["frame"].visible:
                shift = np.asarray(slot.nodes["frame"].position)
                bounds.append((lo + shift, hi + shift))
        position, look_at = overview(bounds)
        camera = self.server.initial_camera
        camera.position, camera.look_at, camera.up = position, look_at, (0.0, -1.0, 0.0)

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    # --- GUI -------------------------------------------------------------------------------------
    def _gui(self) -> None:
        gui = self.server.gui
        self.step_slider = gui.add_slider(
            "keyframe",
            min=0,
            max=max(len(self.steps), 1),
            step=1,
            initial_value=len(self.steps),
            disabled=not self.steps,
        )
        self.step_text = gui.add_markdown(self._step_caption())
        self.show_pruned = gui.add_checkbox("pruned (red)", initial_value=True, disabled=not self._any_pruned())
        self.show_est = gui.add_checkbox("estimated trajectory", initial_value=True)
        self.show_gt = gui.add_checkbox("ground truth", initial_value=True)
        self.show_kf = gui.add_checkbox("keyframes", initial_value=True)
        self.pickers: dict[str, Any] = {}  # slot name -> its run menu (a sweep dir's runs)
        for slot in self.slots:
            if len(slot.runs) > 1:
                labels = [run_label(r, slot.root) for r in slot.runs]
                picker = gui.add_dropdown(f"run {slot.name}", tuple(labels), initial_value=slot.scene.label)
                picker.on_update(lambda _, slot=slot, labels=labels: self._pick(slot, labels))
                self.pickers[slot.name] = picker
        self.layout = None
        if len(self.slots) == 2:
            self.layout = gui.add_dropdown("layout", ("side by side", "A only", "B only"), initial_value="side by side")
            self.layout.on_update(lambda _: self._layout())
        self.legend = gui.add_markdown(self._legend())
        self.step_slider.on_update(lambda _: self._on_slider())
        for box in (self.show_pruned, self.show_est, self.show_gt, self.show_kf):
            box.on_update(lambda _: self._visibility())

    def _all_steps(self) -> list[int]:
        return sorted({k for slot in self.slots for k in slot.scene.steps})

    def _any_pruned(self) -> bool:
        return any(slot.scene.pruned for slot in self.slots)

    def _step(self) -> int | None:
        """The keyframe the slider points at; None at its right end (the final map)."""
        i = int(self.step_slider.value)
        return self.steps[i] if i < len(self.steps) else None

    def _step_caption(self) -> str:
        kf = self._step() if self.steps else None
        return f"**{FINAL}**" if kf is None else f"**after keyframe {kf}'s prune**"

    def _legend(self) -> str:
        lines = [f"**{slot.name}**: {slot.scene.label} ({len(slot.scene.splats)} Gaussians)" for slot in self.slots]
        lines.append("blue: estimate, grey: ground truth, orange: keyframes, red: pruned")
        return "  \n".join(lines)

    def _pick(self, slot: Slot, labels: list[str]) -> None:
        run = slot.runs[labels.index(self.pickers[slot.name].value)]
        with self.lock:
            try:
                scene = read_run(run, run_label(run, slot.root))
            except BenchError as exc:  # a sweep's failed run has no map: say so on the page, keep showing the last
                self.legend.content = f"{self._legend()}  \n**error:** {exc}"
                return
            slot.scene = scene
            slot.shown_step = None
            for handle in reversed(slot.nodes.values()):  # the frame last: removing it takes its children along
                handle.remove()
            slot.nodes.clear()
            self._draw(slot)
            self.steps = self._all_steps()
            self.step_slider.max = max(len(self.steps), 1)
            self.step_slider.value = len(self.steps)
            self.step_slider.disabled = not self.steps
            self.show_pruned.disabled = not self._any_pruned()
            self.legend.content = self._legend()
            self._layout()

    # --- the scene -------------------------------------------------------------------------------
    def _splats(self, slot: Slot, splats: Splats) -> None:
        slot.nodes["map"] = self.server.scene.add_gaussian_splats(
            f"/{slot.name}/map", splats.centers, splats.covariances, splats.rgbs, splats.opacities
        )

    def _draw(self, slot: Slot) -> None:
        scene, add = slot.scene, self.server.scene
        slot.nodes["frame"] = add.add_frame(f"/{slot.name}", show_axes=False)
        self._splats(slot, scene.splats)
        for name, points, rgb, px in [
            ("traj_est", scene.traj_est, EST_RGB, 3.0),
            ("traj_gt", scene.traj_gt, GT_RGB, 2.0),
        ]:
            if points is not None and len(points) > 1:  # a line strip, px wide on screen
                slot.nodes[name] = add.add_line_segments(
                    f"/{slot.name}/{name}", polyline_segments(points), rgb, thickness=px, thickness_units="screen"
                )
        size = _frustum_size(scene)
        for cam in scene.cameras:
            slot.nodes[f"kf_{cam.kf:03d}"] = add.add_camera_frustum(
                f"/{slot.name}/keyframes/kf_{cam.kf:03d}",
                fov=float(np.radians(scene.vfov_deg)),
                aspect=scene.aspect,
                scale=size,
                color=KF_RGB,
                image=cam.image,
                wxyz=cam.wxyz,
                position=cam.position,
            )
        self._show_step(slot)

    def show(self, kf: int | None) -> None:
        """Step to keyframe ``kf`` (one of ``steps``), or the final map for None: what moving the slider does."""
        self._check_step(kf)
        self.error = None
        self.step_slider.value = len(self.steps) if kf is None else self.steps.index(kf)  # its on_update draws
        if self.error is not None:
            raise self.error

    def _on_slider(self) -> None:
        """The slider moved (on the page, or ``show``): draw that step; a file that cannot be read is said on the
        page (and raised again by ``show``), not in viser's thread."""
        try:
            self._show_step()
        except BenchError as exc:
            self.error = exc
            self.legend.content = f"{self._legend()}  \n**error:** {exc}"

    def _check_step(self, kf: int | None) -> None:
        if kf is not None and kf not in self.steps:
            have = f"one of the keyframes {', '.join(map(str, self.steps))}" if self.steps else "no keyframe steps"
            raise ConfigError(
                f"--keyframe: expected {have} (snapshots: save_maps=every_keyframe; prunes: viz.pruning=true), "
                f"found {kf}"
            )

    def _show_step(self, only: Slot | None = None) -> None:
        """The map and the pruned centres as they were after the slider's keyframe."""
        with self.lock:
            self._draw_step(self._step() if self.steps else None, [only] if only is not None else self.slots)

    def _draw_step(self, kf: int | None, slots: list[Slot]) -> None:
        self.step_text.content = self._step_caption()
        for slot in slots:
            scene = slot.scene
            # the map: that keyframe's snapshot, the latest one before it, else the final map
            snap = max((k for k in scene.snapshots if kf is not None and k <= kf), default=None)
            if snap != slot.shown_step:
                slot.nodes["map"].remove()
                self._splats(slot, scene.splats if snap is None else load_snapshot(scene.snapshots[snap]))
                slot.shown_step = snap
            if "pruned" in slot.nodes:
                slot.nodes.pop("pruned").remove()
            points = pruned_points(scene.pruned[kf]) if kf in scene.pruned else None
            if points is not None and len(points):
                slot.nodes["pruned"] = self.server.scene.add_point_cloud(
                    f"/{slot.name}/pruned",
                    points,
                    PRUNED_RGB,
                    point_size=_frustum_size(scene) * 0.3,
                    precision="float32",  # float16 would move a centre 100 m out by centimetres
                )
        self._visibility()

    def _visibility(self) -> None:
        shown = {"pruned": self.show_pruned.value, "traj_est": self.show_est.value, "traj_gt": self.show_gt.value}
        for slot in self.slots:
            for name, handle in slot.nodes.items():
                if name in shown:
                    handle.visible = shown[name]
                elif name.startswith("kf_"):
                    handle.visible = self.show_kf.value

    def _layout(self) -> None:
        """Two runs: B beside A, or one of them alone at the origin; then the camera takes in what shows."""
        if len(self.slots) == 2:
            a, b = self.slots
            choice = self.layout.value if self.layout is not None else "side by side"
            a.nodes["frame"].visible = choice != "B only"
            b.nodes["frame"].visible = choice != "A only"
            b.nodes["frame"].position = side_by_side(a.scene, b.scene) if choice == "side by side" else np.zeros(3)
        self._aim()

    def stop(self) -> None:
        self.server.stop()


def _frustum_size(scene: RunScene) -> float:
    """Frustum depth in m: a 40th of the trajectory's extent (a 20th of the map's without one), at least 5 cm."""
    points = scene.traj_est if len(scene.traj_est) > 1 else scene.splats.centers
    span = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
    return max(span / (40 if points is scene.traj_est else 20), 0.05)
