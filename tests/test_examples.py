"""The examples run, tiny, so they never rot (as Warp's own test suite does with its examples)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_example(*args, timeout=600):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-2000:]
    return r


def test_seed_figures_all_render_tiny(tmp_path):
    import pathtracer

    run_example("examples/seed_figures.py", "--scale", "0.04", "--spp-scale", "0.02", "--out", str(tmp_path))
    sys.path.insert(0, str(ROOT / "examples"))
    from seed_figures import FIGURES

    for fig in FIGURES.values():
        img = pathtracer.read_image(str(tmp_path / f"{fig.name}.png"))
        assert img.shape == (24, 32, 3)
        assert img.max() > 0.05, fig.name  # something visible in every figure


def test_seed_figures_commands_are_cli_commands():
    r = run_example("examples/seed_figures.py", "--commands")
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 9 and all(" pathtracer scenes/" in line for line in lines)


def test_compare_mitsuba_tiny(tmp_path):
    pytest.importorskip("mitsuba")
    r = run_example("examples/compare_mitsuba.py", "scenes/cornell_box.xml", "--spp", "64", "--batches", "16",
                    "--width", "24", "--height", "18", "--variant", "scalar_rgb", "--out", str(tmp_path))
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert np.isfinite(result["relmse"]) and result["noise_floor"] > 0
    # both unbiased: the difference is what the noise explains (a loose bound: 64 spp, 432 pixels)
    assert result["ratio"] < 1.5, result
