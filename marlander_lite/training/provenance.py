"""Where a run came from: the code's commit and the hashes of the files it wrote.

Every run's ``config.json`` records ``provenance`` (the git commit of the library that trained it, and
whether the working tree had uncommitted changes) when it starts, and the digest of its policy file's content
(:func:`policy_digest`) when it finishes. With the resolved config saved next to them, that is what
:mod:`marlander_lite.training.reproduce_shipped` needs to retrain a shipped artifact and say whether
today's code still makes the same file.
"""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path
from typing import Any

import marlander_lite

PACKAGE_ROOT = Path(marlander_lite.__file__).resolve().parents[1]


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, as hex."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def policy_digest(path: str | Path) -> str:
    """SHA-256 of a policy file's *content*: its metadata (sorted by key) and tensors (sorted by name).

    Not the file's bytes: safetensors writes the metadata entries in an order that changes from one
    process to the next, so two byte-different files can hold the same policy. Equal digests mean
    equal contracts and bit-identical weights.
    """
    from safetensors import safe_open

    digest = hashlib.sha256()
    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata() or {}
        for key in sorted(metadata):
            digest.update(f"{key}={metadata[key]}\n".encode())
        for name in sorted(handle.keys()):
            tensor = handle.get_tensor(name)
            digest.update(f"{name}:{tensor.dtype}:{tensor.shape}\n".encode())
            digest.update(tensor.tobytes())
    return digest.hexdigest()


def code_version() -> dict[str, Any]:
    """``{"commit": SHA or None, "dirty": bool or None}`` of the library's git checkout.

    ``None`` when the library is not a git checkout (installed from a wheel) or git is missing. ``dirty``
    counts only changes to tracked files under ``marlander_lite/`` (the code that trains), not data or docs.
    """

    def git(*args: str) -> str | None:
        try:
            result = subprocess.run(
                ["git", "-C", str(PACKAGE_ROOT), *args], capture_output=True, text=True, timeout=10, check=False
            )
        except (OSError, subprocess.TimeoutExpired):
            return None
        return result.stdout.strip() if result.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {"commit": None, "dirty": None}
    changes = git("status", "--porcelain", "--untracked-files=no", "--", "marlander_lite")
    return {"commit": commit, "dirty": bool(changes)}
