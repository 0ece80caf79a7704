"""Every loader keeps the documented promise on refused input (issue 40, class H).

docs/cli.md, "Errors": bad data files (a missing path, a malformed file, NaN poses, duplicate or unsorted
timestamps, a singular calibration) are found when the data is opened, before the SLAM loop. This
is that promise for every loader and every kind of file it reads, opened directly (an accepted
file would otherwise cost a whole run). The EuRoC camera list and ground truth and the KITTI
times accepted duplicate and unsorted timestamps; an EuRoC run over an unsorted camera list ended
``ok`` with a far worse ATE.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from bench.cli import entry as cli
from bench.errors import DatasetError
from bench.run.config import to_run_config
from bench.run.setup import open_seq
from tests.test_bad_input import _lines, _tum_copy


def _swap(i: int, j: int) -> Callable[[list[str]], None]:
    def edit(lines: list[str]) -> None:
        lines[i], lines[j] = lines[j], lines[i]

    return edit


def _repeat(i: int) -> Callable[[list[str]], None]:
    return lambda lines: lines.insert(i + 1, lines[i])


def _field(i: int, k: int, value: str, sep: str = " ") -> Callable[[list[str]], None]:
    def edit(lines: list[str]) -> None:
        parts = lines[i].split(sep)
        parts[k] = value
        lines[i] = sep.join(parts)

    return edit


KITTI = "sequences/06"
EUROC_CAM = "V1_01_micro/mav0/cam0/data.csv"
EUROC_GT = "V1_01_micro/mav0/state_groundtruth_estimate0/data.csv"
TUM = "rgbd_dataset_freiburg1_test"
SEVEN = "seq/frame-000002.pose.txt"

# name: (dataset, file under the root, edit of its lines, part of the error line)
CASES: dict[str, tuple[str, str, Callable[[list[str]], None], str]] = {
    "kitti-times-duplicate": ("kitti", f"{KITTI}/times.txt", _field(3, 0, "2.077935e-01"), "duplicate of line 3"),
    "kitti-times-unsorted": ("kitti", f"{KITTI}/times.txt", _swap(2, 3), "expected strictly increasing"),
    "kitti-times-nan": ("kitti", f"{KITTI}/times.txt", _field(2, 0, "nan"), "expected finite numbers"),
    "kitti-times-text": ("kitti", f"{KITTI}/times.txt", _field(2, 0, "x"), "expected one number"),
    "kitti-poses-nan": ("kitti", "poses/06.txt", _field(4, 3, "nan"), "expected finite numbers"),
    "kitti-poses-text": ("kitti", "poses/06.txt", _field(4, 3, "x"), "expected 12 numbers"),
    "euroc-camera-duplicate": ("euroc", EUROC_CAM, _field(3, 0, "1403715273312143104", ","), "duplicate of line 3"),
    "euroc-camera-unsorted": ("euroc", EUROC_CAM, _swap(2, 3), "expected strictly increasing"),
    "euroc-camera-text": ("euroc", EUROC_CAM, _field(2, 0, "x", ","), "expected 'timestamp_ns,filename'"),
    "euroc-gt-duplicate": ("euroc", EUROC_GT, _repeat(3), "duplicate of line 4"),
    "euroc-gt-unsorted": ("euroc", EUROC_GT, _swap(2, 3), "expected strictly increasing"),
    "euroc-gt-nan": ("euroc", EUROC_GT, _field(2, 1, "nan", ","), "expected finite numbers"),
    "euroc-gt-text": ("euroc", EUROC_GT, _field(2, 1, "x", ","), "expected 'timestamp_ns,px"),
    "tum-gt-duplicate": ("tum", f"{TUM}/groundtruth.txt", _repeat(2), "duplicate of line 3"),
    "tum-gt-unsorted": ("tum", f"{TUM}/groundtruth.txt", _swap(2, 3), "expected strictly increasing"),
    "tum-gt-nan": ("tum", f"{TUM}/groundtruth.txt", _field(2, 1, "nan"), "expected finite numbers"),
    "tum-rgb-duplicate": ("tum", f"{TUM}/rgb.txt", _repeat(2), "duplicate of line 3"),
    "tum-depth-unsorted": ("tum", f"{TUM}/depth.txt", _swap(2, 3), "expected strictly increasing"),
    "tum-rgb-nan": ("tum", f"{TUM}/rgb.txt", _field(2, 0, "nan"), "expected finite numbers"),
    "sevenscenes-pose-nan": ("sevenscenes", SEVEN, _field(1, 3, "nan"), "expected finite numbers"),
    "sevenscenes-pose-text": ("sevenscenes", SEVEN, _field(1, 3, "x"), "expected 16 numbers (a 4x4 matrix)"),
    "sevenscenes-pose-short": ("sevenscenes", SEVEN, lambda lines: lines.pop(), "found 12"),
    "sevenscenes-pose-scaled": ("sevenscenes", SEVEN, _field(0, 0, "2.0"), "expected a rigid transform"),
}


def _sevenscenes_copy(shared: Path, tmp_path: Path, n_frames: int = 3) -> Path:
    """A root in tmp_path whose ``seq/`` links the first frames of the shared 7-Scenes sequence."""
    src = shared / "data" / "sevenscenes" / "seq"
    seq = tmp_path / "sevenscenes" / "seq"
    seq.mkdir(parents=True)
    for n in range(n_frames):
        for suffix in ("color.jpg", "depth.png", "pose.txt"):
            (seq / f"frame-{n:06d}.{suffix}").symlink_to(src / f"frame-{n:06d}.{suffix}")
    return tmp_path / "sevenscenes"


def _root(dataset: str, tmp_path: Path, request: pytest.FixtureRequest) -> tuple[Path, str]:
    if dataset == "tum":
        return _tum_copy(tmp_path), "fr1_test"
    if dataset == "kitti":
        return request.getfixturevalue("make_kitti_copy")(), "06"
    if dataset == "sevenscenes":
        return _sevenscenes_copy(request.getfixturevalue("shared"), tmp_path), "seq"
    return request.getfixturevalue("euroc_copy"), "V1_01_micro"


def _own_copy(root: Path, path: Path) -> Path:
    """``path`` made a file of this test's own: a linked folder or file on its way (the fixtures link
    the read-only shared data) is replaced by a copy, so an edit never reaches the shared data."""
    part = root
    for name in path.relative_to(root).parts:
        part = part / name
        if part.is_symlink():
            target = part.resolve()
            part.unlink()
            (shutil.copytree if target.is_dir() else shutil.copy)(target, part)
    assert path.resolve().is_relative_to(root.resolve()), path.resolve()
    return path


def _open(dataset: str, root: Path, seq: str, read: int = 0) -> None:
    """Open the sequence, then read its first ``read`` frames as a run does."""
    overrides = [f"dataset={dataset}", f"seq={seq}", f"dataset.root={root}"]
    overrides += [] if dataset in ("tum", "sevenscenes") else ["dataset.cache_dir=null"]
    sequence = open_seq(to_run_config(cli.compose(overrides)))
    for i in range(min(read, len(sequence))):
        sequence[i]


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_loader_refuses_what_the_docs_say_it_refuses(
    name: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    dataset, rel, edit, says = CASES[name]
    root, seq = _root(dataset, tmp_path, request)
    _open(dataset, root, seq)  # intact: opens
    path = _own_copy(root, root / rel)
    _lines(path, edit)
    with pytest.raises(DatasetError) as err:
        _open(dataset, root, seq)
    message = str(err.value)
    assert says in message and "\n" not in message, message


@pytest.mark.parametrize("dataset", ["kitti", "euroc", "tum", "sevenscenes"])
def test_a_missing_root_is_refused(dataset: str, tmp_path: Path) -> None:
    seq = {"kitti": "06", "euroc": "V1_01_micro", "tum": "fr1_test", "sevenscenes": "seq"}[dataset]
    with pytest.raises(DatasetError, match="not found|missing|expected"):
        _open(dataset, tmp_path / "nowhere", seq)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("1 0 0 0 0 1 0 0 0 0 1 0\n" * 20, "expected a route that moves along the ground"),
        ("1 0 0 0 0 1 0 0 0 0 1 nan\n" * 20, "expected 12 finite numbers per line"),
        ("1 0 0\n" * 20, "expected 12 finite numbers per line"),
        ("", "expected at least n_frames=12 poses, found 0"),
    ],
)
def test_the_synthetic_route_file_refuses_what_it_cannot_drive(text: str, says: str, tmp_path: Path) -> None:
    route = tmp_path / "route.txt"
    route.write_text(text)
    with pytest.raises(DatasetError) as err:
        open_seq(to_run_config(cli.compose(["+experiment=tiny", f"dataset.route_file={route}"])))
    assert says in str(err.value)


# ------------------------------------------------------------------ images checked for what they are (issue 62, H)
def _sixteen_bit(path: Path) -> None:
    """The frame written again as a 16-bit PNG of the same 8-bit values (as a careless export does)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    path.unlink()
    assert cv2.imwrite(str(path), img.astype("uint16"))


def _eight_bit(path: Path) -> None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    path.unlink()
    assert cv2.imwrite(str(path), (img // 256).astype("uint8"))


def _cut(path: Path) -> None:
    """The file cut to its first third (a copy interrupted)."""
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(data[: len(data) // 3])


IMAGE_CASES: dict[str, tuple[str, str, Callable[[Path], None], str]] = {
    "kitti-frame-16-bit": ("kitti", f"{KITTI}/image_0/000002.png", _sixteen_bit, "expected an 8-bit png, found a 16"),
    "kitti-frame-cut": ("kitti", f"{KITTI}/image_1/000002.png", _cut, "expected a whole png, found one cut short"),
    "euroc-frame-cut": ("euroc", "V1_01_micro/mav0/cam0/data/1403715273312143104.png", _cut, "found one cut short"),
    "sevenscenes-colour-cut": ("sevenscenes", "seq/frame-000002.color.jpg", _cut, "expected a whole jpeg"),
    "sevenscenes-depth-8-bit": ("sevenscenes", "seq/frame-000002.depth.png", _eight_bit, "found an 8-bit gray png"),
    "tum-colour-cut": ("tum", f"{TUM}/rgb/FIRST", _cut, "found one cut short"),
}
# checked when the sequence is opened (datasets/sevenscenes/README.md); the others when the frame is read
AT_OPEN = ("sevenscenes-colour-cut", "sevenscenes-depth-8-bit")


@pytest.mark.parametrize("name", sorted(IMAGE_CASES))
def test_an_image_of_the_wrong_bit_depth_or_cut_short_is_refused(
    name: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    dataset, rel, spoil, says = IMAGE_CASES[name]
    root, seq = _root(dataset, tmp_path, request)
    if rel.endswith("FIRST"):  # the first colour frame of the sequence, whatever its name
        rel = str(min((root / rel).parent.iterdir()).relative_to(root))
    path = _own_copy(root, root / rel)
    _open(dataset, root, seq, read=4)  # intact: opens and reads
    spoil(path)
    with pytest.raises(DatasetError) as err:  # at open, or when the frame is read, as the run reads it
        _open(dataset, root, seq, read=0 if name in AT_OPEN else 4)
    message = str(err.value)
    assert says in message and str(path.name) in message and "\n" not in message, message
