"""What makes two runs "the same run" for resume, and why a stored one is redone.

A sweep rerun skips a run dir whose finished results match on three things: the resolved config
(its hash), the code version (git commit, dirty flag and a hash of the uncommitted code diff) and
a fingerprint of the input files. Why all three: with the config alone, a run over a broken file
(a negative focal length ending ``lost``) stayed ``lost`` after the file was fixed, and results
of old code were kept after a fix. Every redo logs its reason.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bench.fileio import content_digest

SMALL_FILE_BYTES = 1 << 20  # text files (calib, lists, ground truth) keep a digest each; larger ones share one
FINISHED = ("ok", "lost")  # statuses a rerun keeps; failed and interrupted runs are redone


def input_fingerprint(paths: Iterable[Path]) -> dict[str, str]:
    """{name: digest}: small text files one digest each, images (and other large files) one digest of their
    names, sizes and contents together.

    Contents, not modification times: a dataset copied to a cluster's scratch disk, restored from a backup
    or remounted between sessions keeps its bytes but not its mtimes, and with mtimes in the key every
    finished run of a long study was redone. The run reads every frame anyway; hashing them adds a small
    part of that read (BLAKE2b, which is faster than SHA-256 here and as good for telling files apart).
    """
    out: dict[str, str] = {}
    images = hashlib.blake2b(digest_size=16)
    n_images = 0
    for path in paths:
        path = Path(path)
        try:
            st = path.stat()
        except OSError:
            out[str(path)] = "missing"
            continue
        if path.suffix.lower() in (".png", ".jpg", ".jpeg") or st.st_size > SMALL_FILE_BYTES:
            content = content_digest(path)
            images.update(f"{path}\0{st.st_size}\0{content}\n".encode())
            n_images += 1
        else:
            out[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    if n_images:
        out[f"images ({n_images} files)"] = images.hexdigest()[:16]
    return out


def resume_key(config_hash: str, code: dict[str, Any], inputs: dict[str, str]) -> dict[str, Any]:
    return {"config_hash": config_hash, "code_version": code, "inputs": inputs}


def redo_reason(stored: dict[str, Any] | None, key: dict[str, Any]) -> str | None:
    """None when ``stored`` holds finished results of the same run (skip it); else why it is redone.

    ``stored`` is a previous ``metrics.json``; ``key`` comes from ``resume_key``.
    """
    if stored is None:
        return "no previous results"
    status = stored.get("status")
    if status not in FINISHED:
        return f"the previous run ended {status}"
    run = stored.get("run") or {}
    if run.get("config_hash") != key["config_hash"]:
        return f"config changed (hash {run.get('config_hash')} -> {key['config_hash']})"
    old_code, new_code = run.get("code_version"), key["code_version"]
    if not same_code(old_code, new_code):
        return f"code version changed ({_code(old_code)} -> {_code(new_code)})"
    old_in, new_in = run.get("inputs"), key["inputs"]
    if old_in != new_in:
        if not isinstance(old_in, dict):
            return "input files not fingerprinted by the previous run"
        changed = sorted(k for k in set(old_in) | set(new_in) if old_in.get(k) != new_in.get(k))
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        return f"input files changed: {', '.join(_short(c) for c in changed[:3])}{more}"
    return None


def same_code(old: Any, new: Any) -> bool:
    """Equal code versions; where both carry ``code_tree``, the commit itself may differ (a commit
    that changed no code under ``provenance.CODE_PATHS``)."""
    if isinstance(old, dict) and isinstance(new, dict) and old.get("code_tree") and new.get("code_tree"):
        return all(old.get(k) == new.get(k) for k in ("code_tree", "git_dirty", "diff_sha", "package"))
    return old == new


def _code(code: Any) -> str:
    if not isinstance(code, dict):
        return "unknown"
    commit = (code.get("git_commit") or "no commit")[:12]
    dirty = code.get("git_dirty")
    if dirty:
        return f"{commit}+dirty {str(code.get('diff_sha') or '')[:8]}".rstrip()
    return commit if dirty is not None else f"{commit} (dirty unknown)"


def _short(path: str) -> str:
    parts = Path(path).parts
    return os.path.join(*parts[-3:]) if len(parts) > 3 else path
