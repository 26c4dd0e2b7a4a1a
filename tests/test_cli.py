"""The command line: option checks (one-line errors, exit status 2), plumbing to load_file/render, output."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import pathtracer
from pathtracer import cli, imageio, jobs
from pathtracer.errors import ImageIOError, RenderError, SceneError

ROOT = Path(__file__).resolve().parents[1]



# --- helpers ------------------------------------------------------------------------------------


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("WARP_CACHE_PATH", os.path.join(tempfile.gettempdir(), "pathtracer-test-warp-cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def run_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pathtracer", *map(str, args)],
        cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=timeout,
    )


def _is_warp_noise(line: str) -> bool:
    """Warp's own driver/toolkit warnings (e.g. 'Warp CUDA warning: Could not find ... CUDA driver')."""
    return line.startswith("Warp") and "warning" in line.lower()


def stderr_lines(text: str) -> list[str]:
    """Non-empty stderr lines, keeping only what is left after a progress bar's last carriage return."""
    lines = (l.rsplit("\r", 1)[-1].strip() for l in text.split("\n"))
    return [l for l in lines if l and not _is_warp_noise(l)]


def assert_one_line_error(rc: int, stderr: str, expect: str | None = None) -> str:
    assert rc == 2, stderr
    assert "Traceback" not in stderr
    lines = stderr_lines(stderr)
    assert len(lines) == 1, stderr
    assert lines[0].startswith("pathtracer: error: "), lines[0]
    assert len(lines[0]) > len("pathtracer: error: ")
    if expect is not None:
        assert re.search(expect, lines[0]), lines[0]
    return lines[0]


@pytest.fixture
def scene_file(tmp_path) -> Path:
    p = tmp_path / "scene.xml"
    p.write_text("<scene version='3.0.0'/>\n")  # only has to exist for the fakes
    return p


class FakeScene:
    spp = 3
    width, height = 5, 4


class Fakes:
    """Records what the CLI passes to load_file and render."""

    def __init__(self, with_stats: bool = True):
        self.load_calls: list[tuple[str, dict]] = []
        self.render_calls: list[dict] = []
        self.with_stats = with_stats

    def load_file(self, path, **params):
        self.load_calls.append((path, params))
        return FakeScene()

    def render_with_stats(self, scene, stats=None, **kwargs):
        self.render_calls.append(dict(kwargs, stats=stats))
        img = np.full((scene.height, scene.width, 3), 0.25, np.float32)
        if stats is not None:
            spp = kwargs.get("spp") or scene.spp
            stats.update(seconds=0.5, compile_seconds=1.25, samples=scene.width * scene.height * spp, discarded=0)
        return img

    def render_without_stats(self, scene, spp=None, max_depth=None, seed=0, device=None, light_samples=None,
                             rr=None, threads=None, view="radiance", progress=True, callback=None):
        self.render_calls.append(dict(spp=spp, max_depth=max_depth, seed=seed, device=device, view=view, progress=progress))
        return np.zeros((scene.height, scene.width, 3), np.float32)


@pytest.fixture
def fakes(monkeypatch) -> Fakes:
    f = Fakes()
    monkeypatch.setattr(pathtracer, "load_file", f.load_file, raising=False)
    monkeypatch.setattr(pathtracer, "render", f.render_with_stats, raising=False)
    return f


# --- error cases through a real process ---------------------------------------------------------

SUBPROCESS_ERRORS = [
    (["{scene}"], r"required: -o/--output"),
    (["{scene}", "-o", "{tmp}/a.exr", "--spp", "0"], r"--spp must be > 0, got 0"),
    (["{scene}", "-o", "{tmp}/a.exr", "--max-depth", "0"], r"--max-depth"),
    (["{scene}", "-o", "{tmp}/a.exr", "--seed", str(2**32)], r"--seed"),
    (["{scene}", "-o", "{tmp}/a.exr", "--device", "tpu"], r"unknown device 'tpu'"),
    (["{scene}", "-o", "{tmp}/a.exr", "-D", "spp"], r"-D 'spp': expected NAME=VALUE"),
    (["{scene}", "-o", "{tmp}/a.jpg"], r"a\.jpg: unsupported output format \(\.jpg\); supported: \.exr, \.png"),
    (["{scene}", "-o", "{tmp}/missing/a.exr"], r"output directory .*missing does not exist"),
    (["{tmp}/nope.xml", "-o", "{tmp}/a.exr"], r"nope\.xml: cannot read scene: no such file"),
    (["{scene}", "-o", "{tmp}/a.exr", "--spp", "many"], r"argument --spp: invalid int value: 'many'"),
    (["{scene}", "-o", "{tmp}/a.exr", "--stats", "{tmp}/missing/s.json"], r"s\.json: cannot write statistics there"),
    (["{scene}", "-o", "{tmp}/a.exr", "--light-tracing", "maybe"], r"argument --light-tracing: invalid choice"),
]


SUBPROCESS_IDS = ["no-output", "spp", "max-depth", "seed", "device", "define", "extension", "missing-dir",
                  "missing-scene", "argparse-type", "stats-dir", "light-tracing-choice"]


@pytest.mark.parametrize("argv,expect", SUBPROCESS_ERRORS, ids=SUBPROCESS_IDS)
def test_subprocess_errors_are_one_line(tmp_path, scene_file, argv, expect):
    argv = [a.format(scene=scene_file, tmp=tmp_path) for a in argv]
    r = run_cli(*argv)
    assert_one_line_error(r.returncode, r.stderr, expect)
    assert r.stdout == "" or all(_is_warp_noise(l) or l.startswith("Warp ") for l in r.stdout.splitlines())
    assert sorted(os.listdir(tmp_path)) == ["scene.xml"]


def test_subprocess_version_and_help():
    r = run_cli("--version")
    assert r.returncode == 0 and re.fullmatch(r"pathtracer \S+\n", r.stdout), r.stdout
    r = run_cli("--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: pathtracer ")
    for opt in ["-o OUT", "--spp N", "--max-depth D", "--seed S", "--device DEV", "--light-samples K", "--rr",
                "--threads N", "--view", "-D NAME=VALUE", "--no-progress", "--version"]:
        assert opt in r.stdout


@pytest.mark.parametrize("argv,code,out,err", [
    (["--version"], 0, r"pathtracer \S+\n", ""),
    (["missing.xml", "-o", "x.exr"], 2, "", r"pathtracer: error: .*missing\.xml"),
])
def test_the_command_skips_teardown_but_keeps_exit_status_output_and_atexit_handlers(argv, code, out, err):
    """``entry`` leaves by os._exit: its status, its buffered output (a pipe, not a terminal) and the atexit
    handlers of every library must survive that."""
    prog = ("import atexit, sys\n"
            "atexit.register(lambda: print('atexit handler ran', file=sys.stderr))\n"
            f"sys.argv = ['pathtracer'] + {argv!r}\n"
            "from pathtracer.cli import entry\n"
            "entry()\n")
    r = subprocess.run([sys.executable, "-c", prog], cwd=ROOT, env=_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == code, r.stderr
    assert re.fullmatch(out, r.stdout) if out else r.stdout == "", r.stdout
    lines = stderr_lines(r.stderr)
    assert lines[-1] == "atexit handler ran", r.stderr
    if err:
        assert len(lines) == 2 and re.search(err, lines[0]), r.stderr


# --- the same checks in-process (fast), none of which may load the scene --------------------------

INPROCESS_ERRORS = [
    ([], r"required: SCENE, -o/--output"),
    (["--spp", "-3"], r"--spp must be > 0, got -3"),
    (["--max-depth", "-2"], r"--max-depth must be -1 \(unlimited\) or >= 1, got -2"),
    (["--max-depth", "0"], r"got 0"),
    (["--light-samples", "0"], r"--light-samples must be > 0"),
    (["--threads", "0"], r"--threads must be > 0"),
    (["--seed", "-1"], r"--seed must be in \[0, 2\*\*32\), got -1"),
    (["--seed", str(2**32)], r"got 4294967296"),
    (["--device", "gpu"], r"unknown device 'gpu'; expected cpu, cuda or cuda:N"),
    (["--device", "cuda:x"], r"unknown device"),
    (["--rr", "never"], r"argument --rr: invalid choice: 'never'"),
    (["--view", "albedo"], r"argument --view: invalid choice"),
    (["-D", "novalue"], r"expected NAME=VALUE"),
    (["-D", "=3"], r"parameter name"),
    (["-D", "1x=3"], r"parameter name"),
    (["--bogus"], r"unrecognized arguments: --bogus"),
]


@pytest.mark.parametrize("extra,expect", INPROCESS_ERRORS)
def test_inprocess_option_errors(tmp_path, scene_file, fakes, capsys, extra, expect):
    argv = [str(scene_file), "-o", str(tmp_path / "a.exr"), *extra] if extra else []
    rc = cli.main(argv)
    err = capsys.readouterr().err
    assert_one_line_error(rc, err, expect)
    assert fakes.load_calls == [] and fakes.render_calls == []


def test_output_errors_inprocess(tmp_path, scene_file, fakes, capsys):
    (tmp_path / "d.exr").mkdir()
    cases = [
        (tmp_path / "x.tiff", r"unsupported output format \(\.tiff\)"),
        (tmp_path / "noext", r"unsupported output format \(no extension\)"),
        (tmp_path / "d.exr", r"output is a directory"),
        (tmp_path / "no" / "dir" / "x.png", r"does not exist"),
    ]
    for out, expect in cases:
        assert_one_line_error(cli.main([str(scene_file), "-o", str(out)]), capsys.readouterr().err, expect)
    assert fakes.load_calls == []


def test_unwritable_output_directory(tmp_path, scene_file, fakes, capsys, monkeypatch):
    real_access = os.access
    monkeypatch.setattr(cli.os, "access", lambda p, mode: False if str(p) == str(tmp_path) else real_access(p, mode))
    rc = cli.main([str(scene_file), "-o", str(tmp_path / "a.exr")])
    assert_one_line_error(rc, capsys.readouterr().err, r"is not writable")
    assert fakes.load_calls == []


def test_version_and_help_inprocess(capsys):
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("pathtracer ")
    assert cli.main(["-h"]) == 0
    assert "usage: pathtracer" in capsys.readouterr().out


# --- plumbing ------------------------------------------------------------------------------------


def test_defines_reach_load_file(tmp_path, scene_file, fakes):
    argv = [str(scene_file), "-o", str(tmp_path / "a.exr"), "-D", "spp=7", "-D", "expr=a=b", "-D", "empty=",
            "-D", "spp=8", "-D", "_x1= spaced "]
    assert cli.main(argv) == 0
    assert fakes.load_calls == [(str(scene_file), {"spp": "8", "expr": "a=b", "empty": "", "_x1": " spaced "})]


def test_all_options_reach_render(tmp_path, scene_file, fakes, capsys):
    out = tmp_path / "a.exr"
    argv = [str(scene_file), "-o", str(out), "--spp", "16", "--max-depth", "-1", "--seed", str(2**32 - 1),
            "--device", "cpu", "--light-samples", "4", "--rr", "throughput", "--threads", "3",
            "--view", "normal", "--no-progress", "--sampler", "sobol", "--light-sampling", "solid_angle",
            "--light-tracing", "--triangles", "warp", "--stats", str(tmp_path / "s.json")]
    assert cli.main(argv) == 0
    (call,) = fakes.render_calls
    assert isinstance(call.pop("stats"), dict)
    assert isinstance(call.pop("stop"), jobs.StopFlag)  # SIGINT/SIGTERM stop the render through it
    assert call == dict(spp=16, max_depth=-1, seed=2**32 - 1, device="cpu", light_samples=4, rr="throughput",
                        threads=3, view="normal", progress=False, sampler="sobol", light_sampling="solid_angle",
                        light_tracing=True, triangles="warp")
    assert np.array_equal(imageio.read_image(out), np.full((4, 5, 3), 0.25, np.float32))
    written = json.loads((tmp_path / "s.json").read_text())  # what render() put in its stats, plus the command's
    assert written["samples"] == 5 * 4 * 16 and written["wall_seconds"] > 0 and written["output"] == str(out)
    captured = capsys.readouterr()
    assert captured.err == ""
    # 5*4*16 = 320 samples in 0.5 s -> 0.00064 M samples/s
    assert captured.out == f"wrote {out}: 5x4, 16 spp, 0.50 s + 1.25 s compile, 0.00 M samples/s\n"


def test_options_left_out_are_not_passed(tmp_path, scene_file, fakes, capsys):
    out = tmp_path / "a.png"
    assert cli.main([str(scene_file), "-o", str(out), "--device", "cuda:1"]) == 0
    (call,) = fakes.render_calls
    call.pop("stats")
    call.pop("stop")
    assert call == dict(device="cuda:1", view="radiance", progress=True)  # the rest: scene file / defaults
    assert re.fullmatch(rf"wrote {re.escape(str(out))}: 5x4, 3 spp, 0\.50 s \+ 1\.25 s compile, [0-9.]+ M samples/s\n",
                        capsys.readouterr().out)
    assert np.all(imageio.to_srgb8(imageio.read_image(out)) == imageio.to_srgb8(np.float32(0.25)))


def test_render_without_stats_is_timed_by_the_cli(tmp_path, scene_file, fakes, monkeypatch, capsys):
    monkeypatch.setattr(pathtracer, "render", fakes.render_without_stats)
    out = tmp_path / "a.exr"
    assert cli.main([str(scene_file), "-o", str(out), "--spp", "2"]) == 0
    assert fakes.render_calls[0]["spp"] == 2
    line = capsys.readouterr().out
    assert re.fullmatch(rf"wrote {re.escape(str(out))}: 5x4, 2 spp, [0-9.]+ s \(including compile\).*\n", line)


def test_discarded_samples_are_reported(tmp_path, scene_file, fakes, monkeypatch, capsys):
    def render(scene, stats=None, **kw):
        stats.update(seconds=2.0, compile_seconds=0.0, samples=4_000_000, discarded=3)
        return np.zeros((2, 2, 3), np.float32)

    monkeypatch.setattr(pathtracer, "render", render)
    assert cli.main([str(scene_file), "-o", str(tmp_path / "a.exr")]) == 0
    assert capsys.readouterr().out.endswith(": 2x2, 3 spp, 2.00 s + 0.00 s compile, 2.00 M samples/s, 3 non-finite samples discarded\n")


@pytest.mark.parametrize("where,exc", [
    ("load", SceneError("scene.xml", "<shape type='cube'>", "unsupported shape; supported: rectangle, sphere, obj")),
    ("render", RenderError("device 'cuda' requested but CUDA is not available\n(no driver found)")),
    ("write", ImageIOError("a.exr: cannot write: No space left on device")),
])
def test_pathtracer_errors_are_one_line(tmp_path, scene_file, fakes, monkeypatch, capsys, where, exc):
    def boom(*a, **k):
        raise exc

    target = {"load": (pathtracer, "load_file"), "render": (pathtracer, "render"), "write": (cli_imageio(), "write_image")}
    monkeypatch.setattr(*target[where], boom)
    rc = cli.main([str(scene_file), "-o", str(tmp_path / "a.exr")])
    captured = capsys.readouterr()
    line = assert_one_line_error(rc, captured.err)
    assert line == "pathtracer: error: " + " ".join(str(exc).split())
    assert captured.out == ""
    assert sorted(os.listdir(tmp_path)) == ["scene.xml"]


def cli_imageio():
    return imageio  # run() imports write_image from pathtracer.imageio at call time


def test_keyboard_interrupt_during_render(tmp_path, scene_file, fakes, monkeypatch, capsys):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(pathtracer, "render", interrupted)
    assert cli.main([str(scene_file), "-o", str(tmp_path / "a.exr")]) == 130
    captured = capsys.readouterr()
    assert stderr_lines(captured.err) == ["pathtracer: interrupted"]
    assert sorted(os.listdir(tmp_path)) == ["scene.xml"]


@pytest.mark.parametrize("ext,encoder", [(".exr", "_write_exr"), (".png", "_write_png")])
def test_keyboard_interrupt_during_write_leaves_previous_output(tmp_path, scene_file, fakes, monkeypatch, capsys, ext, encoder):
    out = tmp_path / f"a{ext}"
    out.write_bytes(b"previous")

    def interrupted(path, image):
        Path(path).write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(imageio, encoder, interrupted)
    assert cli.main([str(scene_file), "-o", str(out)]) == 130
    assert stderr_lines(capsys.readouterr().err) == ["pathtracer: interrupted"]
    assert out.read_bytes() == b"previous"
    assert sorted(os.listdir(tmp_path)) == sorted(["scene.xml", out.name])


# --- end to end (real loader and renderer) --------------------------------------------------------

TINY_SCENE = """<scene version="3.0.0">
    <default name="spp" value="2"/>
    <integrator type="path">
        <integer name="max_depth" value="3"/>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="60"/>
        <transform name="to_world">
            <lookat origin="0, -3, 3" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <sampler type="independent">
            <integer name="sample_count" value="$spp"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="16"/>
            <integer name="height" value="12"/>
        </film>
    </sensor>
    <shape type="rectangle">
        <bsdf type="diffuse">
            <rgb name="reflectance" value="0.8, 0.6, 0.4"/>
        </bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world">
            <scale value="0.3"/>
            <rotate x="1" angle="180"/>
            <translate value="0, 0, 1.5"/>
        </transform>
        <emitter type="area">
            <rgb name="radiance" value="10, 10, 10"/>
        </emitter>
    </shape>
</scene>
"""


def _tiny_scene_model():
    """TINY_SCENE built by hand, for the real renderer before the XML loader exists."""
    from pathtracer.scene import Camera, Integrator, Material, RectLight, Scene, TriangleMesh

    origin, target, up = np.array([0.0, -3.0, 3.0]), np.zeros(3), np.array([0.0, 0.0, 1.0])
    d = (target - origin) / np.linalg.norm(target - origin)
    left = np.cross(up, d)
    left /= np.linalg.norm(left)
    to_world = np.eye(4)
    to_world[:3, 0], to_world[:3, 1], to_world[:3, 2], to_world[:3, 3] = left, np.cross(d, left), d, origin
    scene = Scene(camera=Camera(to_world, 60.0), width=16, height=12, spp=2, integrator=Integrator(max_depth=3))
    floor = scene.add_material(Material("diffuse", (0.8, 0.6, 0.4)))
    black = scene.add_material(Material("diffuse", (0.0, 0.0, 0.0)))
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    scene.meshes.append(TriangleMesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), quad, None, floor))
    light = RectLight(np.array([0, 0, 1.5]), np.array([0.3, 0, 0]), np.array([0, -0.3, 0]), np.array([0, 0, -1.0]),
                      (10.0, 10.0, 10.0))
    scene.lights.append(light)
    scene.meshes.append(TriangleMesh(light.corners(), quad, None, black, light=0))
    return scene


@pytest.mark.skipif(not hasattr(pathtracer, "render"), reason="pathtracer.render not written yet")
def test_real_render_through_cli(tmp_path, scene_file, monkeypatch, capsys):
    monkeypatch.setattr(pathtracer, "load_file", lambda path, **params: _tiny_scene_model(), raising=False)
    out = tmp_path / "real.exr"
    rc = cli.main([str(scene_file), "-o", str(out), "--spp", "2", "--device", "cpu", "--no-progress", "--seed", "3"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert re.fullmatch(rf"wrote {re.escape(str(out))}: 16x12, 2 spp on cpu, [0-9.]+ s \+ [0-9.]+ s compile, "
                        r"[0-9.]+ M samples/s\n", captured.out), captured.out
    img = imageio.read_image(out)
    assert img.shape == (12, 16, 3) and np.all(np.isfinite(img)) and img.max() > 0


def test_stats_json_from_a_real_render(tmp_path, scene_file, monkeypatch, capsys):
    """--stats writes the issue's fields, with values that agree with each other and with the image."""
    monkeypatch.setattr(pathtracer, "load_file", lambda path, **params: _tiny_scene_model(), raising=False)
    out, path = tmp_path / "real.exr", tmp_path / "stats.json"
    rc = cli.main([str(scene_file), "-o", str(out), "--spp", "16", "--device", "cpu", "--no-progress",
                   "--stats", str(path)])
    assert rc == 0, capsys.readouterr().err
    st = json.loads(path.read_text())
    for key in ("spp", "render_seconds", "compile_seconds", "wall_seconds", "samples_per_second", "relmse_estimate",
                "discarded", "config"):
        assert key in st, key
    assert st["spp"] == 16 and st["discarded"] == 0
    assert 0 < st["render_seconds"] <= st["wall_seconds"]
    assert st["samples_per_second"] == pytest.approx(16 * 16 * 12 / st["render_seconds"])
    assert 0 < st["relmse_estimate"] < np.inf
    assert st["config"]["sampler"] == "sobol" and st["config"]["replicates"] == 2
    assert [p for p in os.listdir(tmp_path) if p.endswith(".tmp")] == []


@pytest.fixture
def tiny_scene(tmp_path) -> Path:
    p = tmp_path / "tiny.xml"
    p.write_text(TINY_SCENE)
    return p


def test_end_to_end_exr_subprocess(tmp_path, tiny_scene):
    out = tmp_path / "tiny.exr"
    r = run_cli(tiny_scene, "-o", out, "--device", "cpu", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert re.search(rf"^wrote {re.escape(str(out))}: 16x12, 2 spp on \w+, .* M samples/s$", r.stdout, re.M), r.stdout
    img = imageio.read_image(out)
    assert img.shape == (12, 16, 3) and img.dtype == np.float32
    assert np.all(np.isfinite(img)) and np.all(img >= 0) and img.max() > 0
    assert sorted(os.listdir(tmp_path)) == ["tiny.exr", "tiny.xml"]


def test_end_to_end_png_inprocess_with_define(tmp_path, tiny_scene, capsys):
    out = tmp_path / "tiny.png"
    rc = cli.main([str(tiny_scene), "-o", str(out), "-D", "spp=3", "--max-depth", "2", "--seed", "7",
                   "--device", "cpu", "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert re.search(r": 16x12, 3 spp on ", captured.out), captured.out  # -D spp=3 reached $spp
    img = imageio.read_image(out)
    assert img.shape == (12, 16, 3) and img.max() > 0


def test_end_to_end_scene_error_is_one_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='teacup'/>\n")
    r = run_cli(bad, "-o", tmp_path / "bad.exr", "--device", "cpu")
    assert_one_line_error(r.returncode, r.stderr, r"bad\.xml")
    assert sorted(os.listdir(tmp_path)) == ["bad.xml"]


def test_end_to_end_cuda_request(tmp_path, tiny_scene):
    """With CUDA: renders. Without: one clear line naming CUDA, exit status 2."""
    out = tmp_path / "c.exr"
    r = run_cli(tiny_scene, "-o", out, "--device", "cuda", "--no-progress")
    if r.returncode == 0:
        assert out.exists()
    else:
        line = assert_one_line_error(r.returncode, r.stderr)
        assert "cuda" in line.lower()
        assert not out.exists()


_GOOD_SHAPE = "<shape type='sphere'><float name='radius' value='1'/></shape>"
_SENSOR = ("<sensor type='perspective'><float name='fov' value='45'/><film type='hdrfilm'>"
           "<integer name='width' value='4'/><integer name='height' value='3'/></film></sensor>")
BAD_SCENES = {
    "malformed XML": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'>", r"line \d+"),
    "unknown plugin": (f"<scene version='3.0.0'>{_SENSOR}<shape type='teacup'/></scene>", r"teacup"),
    "unknown property": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'><float name='radious' value='1'/>"
                         "</shape></scene>", r"radious"),
    "NaN": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'><float name='radius' value='nan'/></shape>"
            "</scene>", r"radius"),
    "Inf": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'><point name='center' value='0, inf, 0'/>"
            "</shape></scene>", r"center"),
    "negative radius": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'><float name='radius' value='-1'/>"
                        "</shape></scene>", r"radius"),
    "zero radius": (f"<scene version='3.0.0'>{_SENSOR}<shape type='sphere'><float name='radius' value='0'/>"
                    "</shape></scene>", r"radius"),
    "empty file": ("", r"empty"),
    "binary file": (bytes(range(256)) * 4, r"bad\.xml"),
    "missing mesh": (f"<scene version='3.0.0'>{_SENSOR}<shape type='obj'><string name='filename' value='no.obj'/>"
                     "</shape></scene>", r"no\.obj"),
    "mesh with no faces": (f"<scene version='3.0.0'>{_SENSOR}<shape type='obj'><string name='filename' "
                           "value='empty.obj'/></shape></scene>", r"empty\.obj"),
}


@pytest.mark.parametrize("case", list(BAD_SCENES))
def test_bad_scene_files_fail_in_one_line_and_write_nothing(tmp_path, case, capsys):
    """Issue 3's bad-input list through the CLI with the real loader: status 2, one line naming the file and the
    problem, no traceback, no output file."""
    text, pattern = BAD_SCENES[case]
    bad = tmp_path / "bad.xml"
    if isinstance(text, bytes):
        bad.write_bytes(text)
    else:
        bad.write_text(text)
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    out = tmp_path / "out.exr"
    rc = cli.main([str(bad), "-o", str(out), "--device", "cpu", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "bad.xml" in lines[0], lines[0]
    assert re.search(pattern, lines[0], re.I), lines[0]
    assert not out.exists() and not [p for p in os.listdir(tmp_path) if p.startswith(".out")]


def test_moment_integrator_layers_go_to_the_exr(tmp_path):
    """A moment scene's EXR holds the image and the nested integrator's layers (Mitsuba's channel names); a PNG
    holds the image, and a note says where the layers would have gone."""
    scene = ROOT / "scenes" / "features" / "integrator_moment.xml"
    exr = tmp_path / "m.exr"
    r = run_cli(scene, "--spp", "4", "-o", exr, "--no-progress")
    assert r.returncode == 0, r.stderr
    layers = pathtracer.read_layers(exr)
    assert sorted(layers) == ["m2_path", "path"]
    img = pathtracer.read_image(exr)
    y = img @ np.array([0.212671, 0.715160, 0.072169])
    np.testing.assert_allclose(layers["path"][..., 1], y, rtol=1e-5, atol=1e-7)  # the mean's Y is the image's
    assert np.all(layers["m2_path"][..., 1] >= layers["path"][..., 1] ** 2 * (1 - 1e-5))  # E[Y^2] >= E[Y]^2
    png = tmp_path / "m.png"
    r = run_cli(scene, "--spp", "4", "-o", png, "--no-progress")
    assert r.returncode == 0 and png.exists()
    assert any("go to .exr files only" in line for line in stderr_lines(r.stderr)), r.stderr
