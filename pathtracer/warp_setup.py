"""One place that initialises Warp: a writable kernel cache, quiet logs, and no backward passes compiled."""

from __future__ import annotations

import os
from pathlib import Path

import warp as wp

_done = False


def default_cache_path() -> str:
    """``$WARP_CACHE_PATH`` if set, else ``~/.cache/pathtracer/warp`` (or a temp folder if home is read-only)."""
    env = os.environ.get("WARP_CACHE_PATH")
    if env:
        return env
    for base in (Path.home() / ".cache", Path(os.environ.get("TMPDIR", "/tmp"))):
        path = base / "pathtracer" / "warp"
        try:
            path.mkdir(parents=True, exist_ok=True)
            if os.access(path, os.W_OK):
                return str(path)
        except OSError:
            continue
    return str(Path.cwd() / ".warp_cache")


def init_warp() -> None:
    """Idempotent ``wp.init()`` with the project's settings."""
    global _done
    if _done:
        return
    wp.config.kernel_cache_dir = default_cache_path()
    wp.config.log_level = 40  # errors only: no per-module build chatter on stdout
    wp.init()
    _done = True
