"""Render jobs (pathtracer/jobs.py): budgets, checkpoints written atomically, resumes bit-identical to renders that
never stopped, SIGINT/SIGTERM and kill -9, refused checkpoints, films too large for the machine."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import pathtracer
from pathtracer import jobs
from pathtracer.errors import RenderError
from pathtracer.imageio import read_image, read_layers
from test_cli import _env, stderr_lines

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
# kill -9 trials: the 20 with PATHTRACER_KILL_TRIALS=20; CI runs a few (each costs a process start)
KILL_TRIALS = int(os.environ.get("PATHTRACER_KILL_TRIALS", "3"))


def small(name: str, w: int = 32, h: int = 24):
    return pathtracer.load_file(str(SCENES / f"{name}.xml"), width=w, height=h)


def stop_after(calls: int):
    """A preview callback and the flag it sets after ``calls`` previews: the job then stops after that unit."""
    flag = jobs.StopFlag()
    seen = []

    def preview(image):
        seen.append(image)
        if len(seen) >= calls:
            flag.set()

    return flag, preview, seen


@pytest.mark.parametrize("name", ["cornell_box", "cornell_box_mirror"])  # the mirror box: auto picks light tracing
def test_interrupted_then_resumed_render_is_bit_identical(tmp_path, name):
    scene = small(name)
    full = pathtracer.render(scene, spp=96, seed=5, progress=False)
    ck = tmp_path / "ck.npz"
    flag, preview, seen = stop_after(2)
    st: dict = {}
    part = pathtracer.render(scene, spp=96, seed=5, progress=False, checkpoint=ck, preview=preview,
                             preview_every=1e-9, stop=flag, stats=st)
    assert st["stop_reason"] == "interrupted" and 0 < st["spp"] < 96, st
    assert np.array_equal(part, seen[-1])  # the image returned is the image so far
    st2: dict = {}
    resumed = pathtracer.render(scene, spp=96, seed=5, progress=False, checkpoint=ck, resume=True, stats=st2)
    assert st2["resumed_passes"] == st["spp"] and st2["stop_reason"] == "spp"
    assert st2["config"]["light_tracing"] == st["config"]["light_tracing"]
    assert np.array_equal(resumed, full)
    # and a finished checkpoint resumes to the same image again, with a larger spp continuing it
    again = pathtracer.render(scene, spp=96, seed=5, progress=False, checkpoint=ck, resume=True)
    assert np.array_equal(again, full)


class StopAfterLooks(jobs.StopFlag):
    """A stop flag that is set from the (n+1)-th look at it on (one thread looks once a launch)."""

    def __init__(self, n: int):
        super().__init__()
        self.n, self.looks = n, 0

    def is_set(self) -> bool:
        self.looks += 1
        return self.looks > self.n or super().is_set()


def test_a_stop_during_the_pilot_keeps_both_candidates_and_resumes_bit_identical(tmp_path):
    """The auto pilot looks at the stop flag too: stopped during candidate A's passes or during B's, the render
    returns at once with A's passes as the image (it does not finish the pilot first), the checkpoint keeps both
    candidates' passes, and the resume finishes the pilot, decides as the uninterrupted render did and ends on its
    image bit for bit."""
    scene = small("cornell_box_mirror", 128, 64)  # 4 passes a launch: the pilot's 8 each take two launches
    full_st: dict = {}
    full = pathtracer.render(scene, spp=256, seed=5, progress=False, threads=1, stats=full_st)
    p = full_st["config"]["pilot"]["passes_each"]
    stages = set()
    for n in (1, 2, 5):  # stopped before any pass, after 4 of A's 8, after 4 of B's (with A's 8)
        ck = tmp_path / f"ck{n}.npz"
        st: dict = {}
        part = pathtracer.render(scene, spp=256, seed=5, progress=False, threads=1, checkpoint=ck,
                                 stop=StopAfterLooks(n), stats=st)
        pilot = st["config"]["pilot"]
        assert st["stop_reason"] == "interrupted" and pilot["unfinished"], st
        done = pilot["passes_done"]
        assert done["path"] <= p and done["light_tracing"] < p and st["spp"] == done["path"]
        assert np.all(np.isfinite(part))
        stages.add("none" if done["path"] == 0 else "A" if done["path"] < p else "B")
        st2: dict = {}
        resumed = pathtracer.render(scene, spp=256, seed=5, progress=False, threads=1, checkpoint=ck, resume=True,
                                    stats=st2)
        assert st2["stop_reason"] == "spp" and st2["config"]["light_tracing"] == full_st["config"]["light_tracing"]
        assert st2["config"]["pilot"]["relmse_x_cost_per_pass"] == full_st["config"]["pilot"][
            "relmse_x_cost_per_pass"]
        assert np.array_equal(resumed, full), f"stopped after {n} looks ({done})"
    assert stages == {"none", "A", "B"}, stages  # stopped before the pilot and in each candidate's passes
    # resumed with a larger spp, the pilot keeps the size it began with (spp / 32 would have made it 16 each)
    ck = tmp_path / "ck2.npz"
    pathtracer.render(scene, spp=256, seed=5, progress=False, threads=1, checkpoint=ck, stop=StopAfterLooks(2))
    st3: dict = {}
    pathtracer.render(scene, spp=512, seed=5, progress=False, threads=1, checkpoint=ck, resume=True, stats=st3)
    assert st3["config"]["pilot"]["passes_each"] == p and st3["spp"] == 512
    assert st3["config"]["pilot"]["relmse_x_cost_per_pass"] == full_st["config"]["pilot"]["relmse_x_cost_per_pass"]


def test_a_stop_around_the_pilots_half_way_check_resumes_bit_identical(tmp_path):
    """The open sky at 512 spp: light tracing is checked after 8 of its 16 pilot passes and, losing, renders no
    more. Stopped before B's first pass or among B's first passes, the resume makes the check from the same sums;
    stopped after it, the resume goes on with the decision made. Each ends on the uninterrupted image, having
    rendered B's 8 passes only."""
    scene = small("open_sky", 128, 64)  # 4 passes a launch: A's 16 take four launches, B's 8 two
    full_st: dict = {}
    full = pathtracer.render(scene, spp=512, seed=5, progress=False, threads=1, stats=full_st)
    assert full_st["config"]["pilot"]["lost_at_half"]
    stages = set()
    for n in (6, 7, 8):  # stopped after A's 16 passes, after 4 of B's, after B's 8 (the pilot decided)
        ck = tmp_path / f"ck{n}.npz"
        st: dict = {}
        pathtracer.render(scene, spp=512, seed=5, progress=False, threads=1, checkpoint=ck, stop=StopAfterLooks(n),
                          stats=st)
        pilot = st["config"]["pilot"]
        assert st["stop_reason"] == "interrupted" and st["spp"] >= 16, st
        stages.add(pilot["passes_done"]["light_tracing"] if pilot.get("unfinished") else "decided")
        st2: dict = {}
        resumed = pathtracer.render(scene, spp=512, seed=5, progress=False, threads=1, checkpoint=ck, resume=True,
                                    stats=st2)
        assert st2["config"]["pilot"]["lost_at_half"] and st2["config"]["pilot"]["light_tracing_passes"] == 8
        assert st2["config"]["pilot"]["relmse_x_cost_per_pass"] == full_st["config"]["pilot"]["relmse_x_cost_per_pass"]
        assert np.array_equal(resumed, full), f"stopped after {n} looks"
    assert stages == {0, 4, "decided"}, stages


def test_checkpoints_and_unit_sizes_do_not_change_the_image(tmp_path):
    scene = small("teapot_in_box")
    plain = pathtracer.render(scene, spp=40, seed=2, progress=False)
    often = pathtracer.render(scene, spp=40, seed=2, progress=False, checkpoint=tmp_path / "c.npz",
                              checkpoint_every=1e-9, threads=1)
    assert np.array_equal(plain, often)


@pytest.mark.parametrize("name,target", [("cornell_box", 1e-2), ("cornell_box", 1e-3), ("teapot_in_box", 1e-2)])
def test_target_error_stops_near_the_target_measured_against_mitsuba(name, target):
    """The issue's bound: the relMSE reached, measured against the converged Mitsuba reference (its own noise
    taken out), within 1.5x of the target either way, as the geometric mean of 4 seeds' runs (each within 2.5x); a
    unit sized by time (a second: hundreds of passes of this 64x48 image) overshot 1e-2 by 30-50x before the job
    stepped toward the target.

    Why 4 seeds and not one: since the light tracer took over the walls' caustics, the teapot's error at 1e-2 (about
    50 passes here) sits in a few pixels of its reflections, and one run's estimate of it is noisy. Measured over
    seeds 0-7, relMSE reached / target: 0.48, 0.62, 0.67, 1.62, 0.65, 0.53, 0.83, 0.50 (before: 0.74-1.27, with a
    noisier image that needed 60-90 passes)."""
    from pathtracer.imageio import read_image

    refs = ROOT / "tests" / "data" / "refs"
    ref, var = read_image(refs / f"{name}.exr"), read_image(refs / f"{name}_var.exr")
    scene = pathtracer.load_file(str(SCENES / f"{name}.xml"), width=ref.shape[1], height=ref.shape[0])
    denom = ref.astype(np.float64) ** 2 + 0.01
    ratios = []
    for seed in range(4):
        st: dict = {}
        img = pathtracer.render(scene, target_error=target, seed=seed, progress=False, stats=st)
        measured = float(np.mean((img - ref) ** 2 / denom) - np.mean(var / denom))
        assert st["stop_reason"] == "target_error"
        ratios.append(measured / target)
        assert 1 / 2.5 <= measured / target <= 2.5, (seed, measured, st["spp"], st["relmse_estimate"])
    mean = float(np.exp(np.mean(np.log(ratios))))
    print(f"\n[target error] {name} {target:g}: relMSE reached / target {np.round(ratios, 2)}, geometric mean "
          f"{mean:.2f}")
    assert 1 / 1.5 <= mean <= 1.5, ratios


def test_budgets_stop_the_render_and_say_why(tmp_path):
    scene = small("cornell_box")
    st: dict = {}
    pathtracer.render(scene, time_limit=0.5, progress=False, stats=st)
    assert st["stop_reason"] == "time" and st["spp"] >= 1
    st = {}
    pathtracer.render(scene, target_error=0.05, progress=False, stats=st)
    assert st["stop_reason"] == "target_error" and st["relmse_estimate"] <= 0.05
    assert st["spp"] >= jobs.MIN_TARGET_PASSES
    st = {}
    pathtracer.render(scene, spp=20, time_limit=1e6, target_error=1e-12, progress=False, stats=st)
    assert st["stop_reason"] == "spp" and st["spp"] == 20  # the first bound reached: spp
    for bad in ({"time_limit": 0}, {"target_error": -1.0}, {"resume": True}, {"checkpoint_every": 0.0}):
        with pytest.raises(RenderError):
            pathtracer.render(scene, spp=4, progress=False, checkpoint=None, **bad)


def test_unusable_checkpoints_are_refused_in_one_line(tmp_path):
    scene = small("cornell_box")
    ck = tmp_path / "ck.npz"
    pathtracer.render(scene, spp=8, seed=1, progress=False, checkpoint=ck)
    data = ck.read_bytes()
    other = small("open_sky")
    cases = [
        (dict(scene=other, seed=1), "another scene"),
        (dict(scene=scene, seed=2), "seed = 1"),
        (dict(scene=scene, seed=1, sampler="independent"), "sampler = 'sobol'"),
        (dict(scene=scene, seed=1, spp=4), "holds 8 passes, more than the 4"),
    ]
    for kw, problem in cases:
        kw = dict(dict(spp=16, progress=False, checkpoint=ck, resume=True), **kw)
        with pytest.raises(jobs.CheckpointError) as e:
            pathtracer.render(kw.pop("scene"), **kw)
        assert problem in str(e.value) and "\n" not in str(e.value), str(e.value)
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0xFF
    for blob, problem in ((data[: len(data) // 3], "corrupt or truncated"), (b"", "corrupt or truncated"),
                          (bytes(flipped), "corrupt")):
        ck.write_bytes(blob)
        with pytest.raises(jobs.CheckpointError) as e:
            pathtracer.render(scene, spp=16, seed=1, progress=False, checkpoint=ck, resume=True)
        assert problem in str(e.value) and "\n" not in str(e.value), str(e.value)
    with pytest.raises(jobs.CheckpointError, match="no such file"):
        pathtracer.render(scene, spp=16, progress=False, checkpoint=tmp_path / "none.npz", resume=True)


def test_a_failed_checkpoint_write_keeps_the_previous_one(tmp_path, monkeypatch):
    scene = small("cornell_box")
    ck = tmp_path / "ck.npz"
    pathtracer.render(scene, spp=8, seed=1, progress=False, checkpoint=ck)
    before = ck.read_bytes()

    def fail(f, **arrays):
        f.write(b"half a checkpoint")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(jobs.np, "savez", fail)
    sums, next_pass, config = jobs.read_checkpoint(ck)
    with pytest.raises(RenderError, match="cannot write checkpoint: No space left"):
        jobs.write_checkpoint(ck, sums, next_pass, config)
    assert ck.read_bytes() == before and os.listdir(tmp_path) == ["ck.npz"]  # no temporary left behind


def test_films_too_large_are_refused_before_anything_is_compiled():
    scene = small("cornell_box")
    scene.width = scene.height = 40000
    with pytest.raises(RenderError) as e:
        pathtracer.Renderer(scene, device="cpu")
    assert "40000x40000 film needs about" in str(e.value) and "available" in str(e.value)
    scene.width = scene.height = 200000
    with pytest.raises(RenderError) as e:
        pathtracer.Renderer(scene, device="cpu")
    assert "200000x200000 film" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(RenderError, match="more than 2\\^31 entries"):  # where memory would allow it
        jobs.check_film_size(50000, 50000, 4, False, False, "cuda:99")


# ---------------------------------------------------------------- the command line, in processes


def cli(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pathtracer", *map(str, args)], cwd=ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def job_args(out, ck, spp=2048, every=0.2):
    return [SCENES / "cornell_box.xml", "-o", out, "--spp", spp, "--checkpoint", ck, "--checkpoint-every", every,
            "--no-progress", "-D", "width=48", "-D", "height=36", "--threads", "1"]


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    t0 = time.time()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t0 < timeout, "no checkpoint appeared"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    d = tmp_path_factory.mktemp("ref")
    p = cli(*job_args(d / "ref.exr", d / "ref.npz", every=1e3))
    out, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    return read_image(d / "ref.exr")


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signals_save_the_image_and_the_checkpoint_and_resume_exactly(tmp_path, uninterrupted, sig, code):
    out, ck = tmp_path / "out.exr", tmp_path / "ck.npz"
    p = cli(*job_args(out, ck))
    wait_for(ck, p)
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    assert p.returncode == code, err
    lines = stderr_lines(err)
    assert lines and lines[-1].startswith(f"pathtracer: {'interrupted' if code == 130 else 'terminated'}; saved "), err
    assert "Traceback" not in err
    partial = read_layers(out)
    assert 0 < float(partial["spp"][0, 0]) < 2048 and partial["stderr"].shape == (36, 48, 3)
    p = cli(*job_args(out, ck), "--resume")
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    assert np.array_equal(read_image(out), uninterrupted)


def test_kill_9_at_random_moments_loses_only_the_work_since_the_last_checkpoint(tmp_path, uninterrupted):
    rng = random.Random(20261202)
    for trial in range(KILL_TRIALS):
        out, ck = tmp_path / f"out{trial}.exr", tmp_path / f"ck{trial}.npz"
        p = cli(*job_args(out, ck))
        wait_for(ck, p)
        time.sleep(rng.uniform(0.0, 1.5))
        p.kill()
        p.communicate(timeout=60)
        saved = jobs.read_checkpoint(ck)[0].passes  # whole, whatever the moment of the kill
        p = cli(*job_args(out, ck), "--resume")
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        assert 0 < saved <= 2048
        assert np.array_equal(read_image(out), uninterrupted), f"trial {trial}: resumed from {saved} passes"
