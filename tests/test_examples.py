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


def test_bench_tiny(tmp_path):
    """The speed-against-error bench end to end, tiny and without Mitsuba: the report and its plot are written."""
    pytest.importorskip("matplotlib")
    run_example("examples/bench.py", "--scenes", "cornell_box", "--ladder", "1", "2", "--configs", "K=1", "K=1 sobol",
                "--no-mitsuba", "--no-threads", "--no-compile", "--no-process", "--width", "16", "--height", "12",
                "--ref-spp", "64",
                "--ref-dir", str(tmp_path / "refs"), "--out", str(tmp_path))
    report = (tmp_path / "performance.md").read_text()
    assert "| K=1 | 2 |" in report and "| K=1 sobol | 2 |" in report and "Reference: ours 64 spp" in report
    assert (tmp_path / "performance.png").stat().st_size > 1000
    rows = json.loads((tmp_path / "performance.json").read_text())
    assert len(rows) == 4 and all(r["relmse"] > 0 and r["seconds"] > 0 for r in rows)


def test_bench_auto_against_fixed_tiny():
    """auto against every fixed configuration it could have been: light tracing on and off on a scene with mirrors,
    K = 1 or 2, area or solid-angle sampling, the same seeds, and a ratio to the best of them."""
    import pathtracer

    sys.path.insert(0, str(ROOT / "examples"))
    import bench

    scene = bench.load("cornell_box_mirror", 16, 12)
    ref = pathtracer.render(scene, spp=256, seed=7, progress=False)
    out = bench.auto_vs_fixed("cornell_box_mirror", ref, 16, 12, 32, seeds=2)
    fixed = [label for label, _ in bench.FIXED]
    assert set(out["runs"]) == {"auto", *fixed, *(f"{f} lt" for f in fixed)}
    assert all(r["light_tracing"] == [False, False] for k, r in out["runs"].items() if k in fixed)
    assert all(r["light_tracing"] == [True, True] for k, r in out["runs"].items() if k.endswith(" lt"))
    best = out["runs"][out["best_fixed"]]["efficiency"]
    assert best == max(r["efficiency"] for k, r in out["runs"].items() if k != "auto")
    assert out["ratio"] == pytest.approx(out["runs"]["auto"]["efficiency"] / best)


def test_bench_reads_time_to_error_off_the_ladder():
    sys.path.insert(0, str(ROOT / "examples"))
    from bench import Row, crossing_time

    def ladder(points):
        return [Row("s", "c", spp, t, e, 1.0) for spp, (t, e) in zip((4, 16, 64), points)]

    # relMSE falls 10x per 4x time (faster than 1/t, as Sobol' does): 1e-3 lies between the rungs, log-log
    t, how = crossing_time(ladder([(1.0, 1e-1), (4.0, 1e-2), (16.0, 1e-4)]), 1e-3)
    assert how == "interpolated" and abs(t - 8.0) < 1e-9
    # not reached: extrapolated from the last rung at rate 1/t
    t, how = crossing_time(ladder([(1.0, 1e-1), (4.0, 2.5e-2), (16.0, 6.25e-3)]), 1e-3)
    assert how == "extrapolated" and abs(t - 100.0) < 1e-9


def test_gpu_check_without_cuda_says_so():
    """examples/gpu_check.py is for a CUDA machine; without one it exits cleanly and says why."""
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("a CUDA device is present: the real check is examples/gpu_check.py itself")
    r = run_example("examples/gpu_check.py")
    assert "no CUDA device" in r.stdout


def test_bench_rays_tiny(tmp_path):
    """The ray bench end to end, tiny: every backend agrees with ours on what it hits, and ours has no leaks."""
    run_example("examples/bench_rays.py", "--rounds", "1", "--rays", "2000", "--out", str(tmp_path), "--setup", "2",
                "--warm-memory", "0")
    report = json.loads((tmp_path / "bench_rays.json").read_text())
    for row in report["sets"].values():
        assert row["mrays_per_s"]["wide"] > 0
        assert all(a > 0.99 for a in row["hit_agreement_with_wide"].values())
    assert all(bad == 0 for bad, _ in report["leaks"]["wide"].values())
    (row,) = report["setup"]
    assert row["triangles"] == 320 and row["ready"] > 0 and row["wp_mesh_build"] > 0


def test_inverse_albedo_tiny(tmp_path):
    """The inverse-rendering example, tiny (Mitsuba left out): Adam moves the red wall toward its true colour."""
    out = tmp_path / "inv.json"
    run_example("examples/inverse_albedo.py", "--size", "16", "--iterations", "20", "--spp", "4", "--runs", "1",
                "--target-spp", "64", "--mitsuba-variant", "", "--json", str(out))
    r = json.loads(out.read_text())["first_runs"]["pathtracer"]
    assert r["history"][-1]["param_error"] < 0.5 * r["history"][0]["param_error"]


def test_bench_gradients_tiny(tmp_path):
    out = tmp_path / "g.json"
    run_example("examples/bench_gradients.py", "--size", "8", "--spp", "2", "--reps", "1", "--json", str(out))
    assert set(json.loads(out.read_text())["median_seconds"]) == {
        "render", "render_forward", "render_backward (path replay), 1 key", "render_backward (path replay), all keys",
        "render_backward (forward), 2 keys", "render_loss_gradient (two halves), 1 key",
        "render_loss_gradient (two halves), all keys"}


def test_torch_albedo_tiny():
    """The PyTorch example (an optional extra: skipped where torch is not installed)."""
    pytest.importorskip("torch")
    r = run_example("examples/torch_albedo.py", "--size", "16", "--iterations", "10", "--spp", "2")
    assert "iteration 10:" in r.stdout
