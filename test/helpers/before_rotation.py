"""The repository as it was before rotational slip (issue #21), read from git: the files
that what came after must keep working with (the planar checkpoints, the scene's renders).

Tests that need it skip where the checkout has no git history (an unpacked archive); CI
runs on a clone, which has it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: The last commit before rotational slip: scene version 3 and the planar shipped models.
COMMIT = "ea62097"


def _git() -> str:
    git = shutil.which("git")
    if git is None or subprocess.run([git, "-C", str(ROOT), "cat-file", "-e", COMMIT],
                                     capture_output=True).returncode:
        pytest.skip(f"needs git and commit {COMMIT} (before rotational slip)")
    return git


def file_before(path: str, dest: Path) -> Path:
    """``path`` (relative to the repository) as of :data:`COMMIT`, written to ``dest``."""
    data = subprocess.run([_git(), "-C", str(ROOT), "show", f"{COMMIT}:{path}"],
                          capture_output=True, check=True).stdout
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_bytes(data)
    return dest


def tree_before(path: str, dest: Path) -> Path:
    """The folder ``path`` as of :data:`COMMIT`, extracted under ``dest``; returns ``dest``."""
    archive = subprocess.run([_git(), "-C", str(ROOT), "archive", COMMIT, path],
                             capture_output=True, check=True).stdout
    dest.mkdir(parents=True, exist_ok=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest
