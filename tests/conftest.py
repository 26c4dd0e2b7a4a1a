"""Shared test set-up: a writable Warp kernel cache, one Warp initialisation, and the ``device`` fixture.

The cache folder must be chosen before ``warp`` is imported anywhere (``pathtracer.warp_setup`` reads
``WARP_CACHE_PATH``), so this module sets it first.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".warp_cache"))  # gitignored
os.makedirs(os.environ["WARP_CACHE_PATH"], exist_ok=True)
for p in (str(ROOT), str(Path(__file__).resolve().parent)):
    if p not in sys.path:
        sys.path.insert(0, p)

import pytest  # noqa: E402
import warp as wp  # noqa: E402

from pathtracer.warp_setup import init_warp  # noqa: E402

init_warp()

DEVICES = [pytest.param("cpu", id="cpu")]
if wp.is_cuda_available():
    DEVICES.append(pytest.param("cuda:0", id="cuda", marks=pytest.mark.cuda))


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    """Every kernel test runs on the CPU, and also on the first CUDA device when there is one."""
    return request.param
