"""Image I/O: EXR bit-exact, PNG through exact sRGB, atomic writes, one-line errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pathtracer import imageio
from pathtracer.errors import ImageIOError, PathtracerError
from pathtracer.imageio import read_image, srgb_to_linear, to_srgb8, write_image


def _random_image(seed: int = 0, h: int = 7, w: int = 11) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.random((h, w, 3), dtype=np.float32)


def _listing(directory) -> list[str]:
    return sorted(os.listdir(directory))


# --- EXR ---------------------------------------------------------------------------------------


def test_exr_round_trip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(1)
    # HDR values over many magnitudes, denormal-free zeros, and values > 1 that PNG would clamp.
    img = (rng.random((9, 13, 3)) * 10.0 ** rng.integers(-6, 5, (9, 13, 3))).astype(np.float32)
    img[0, 0] = 0.0
    img[1, 1] = [1e30, 3.5, 65504.0]
    path = tmp_path / "a.exr"
    write_image(path, img)
    back = read_image(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.array_equal(back.view(np.uint32), img.view(np.uint32))
    assert _listing(tmp_path) == ["a.exr"]  # no temp file left behind


def test_exr_stores_standard_rgb_channels(tmp_path):
    import OpenEXR

    img = np.zeros((2, 3, 3), np.float32)
    img[..., 0], img[..., 1], img[..., 2] = 1.0, 2.0, 3.0
    path = tmp_path / "c.exr"
    write_image(path, img)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = {name: c.pixels.copy() for name, c in f.channels().items()}  # closing clears the file's dict
        header = dict(f.header())
    assert set(ch) == {"R", "G", "B"}
    for name, value in zip("RGB", (1.0, 2.0, 3.0)):
        assert ch[name].dtype == np.float32
        assert np.all(ch[name] == value)
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION


def test_float64_input_is_written_as_float32(tmp_path):
    img = _random_image(2).astype(np.float64)
    write_image(tmp_path / "d.exr", img)
    assert np.array_equal(read_image(tmp_path / "d.exr"), img.astype(np.float32))


def test_uppercase_extension_is_accepted(tmp_path):
    img = _random_image(3)
    write_image(tmp_path / "u.EXR", img)
    assert np.array_equal(read_image(tmp_path / "u.EXR"), img)


# --- sRGB / PNG ---------------------------------------------------------------------------------


def test_known_srgb_codes():
    x = np.array([0.0, 1.0, 0.5, 0.0031308, 0.0031308 * 0.5, 0.18, 0.2140, 0.2159], np.float32)
    codes = to_srgb8(x)
    assert codes.dtype == np.uint8
    # 0.0031308 -> 12.92 * x = 0.04045 -> 10.31 -> 10, continuous with the power branch there.
    assert codes.tolist() == [0, 255, 188, 10, 5, 118, 127, 128]
    both = [12.92 * 0.0031308, 1.055 * 0.0031308 ** (1 / 2.4) - 0.055]
    assert abs(both[0] - both[1]) < 1e-6


def test_srgb_clamps_out_of_range_and_non_finite():
    x = np.array([-1.0, -1e-9, 1.0 + 1e-6, 7.0, np.inf, -np.inf, np.nan], np.float32)
    assert to_srgb8(x).tolist() == [0, 0, 255, 255, 255, 0, 0]


def test_srgb_codes_invert_exactly():
    codes = np.arange(256, dtype=np.uint8)
    lin = srgb_to_linear(codes)
    assert lin.dtype == np.float32
    assert lin[0] == 0.0 and lin[255] == pytest.approx(1.0, abs=1e-7)
    assert np.all(np.diff(lin) > 0)
    assert np.array_equal(to_srgb8(lin), codes)  # decode then encode is the identity on codes


def _png_bound(x: np.ndarray) -> np.ndarray:
    """Largest |decode(encode(x)) - x| for linear x in [0, 1].

    Rounding moves the sRGB value s by at most h = 0.5/255; the decoder's slope is increasing in s
    (1/12.92 on the linear branch, 2.4/1.055 ((s + 0.055)/1.055)^1.4 on the power branch), so the
    error is at most h times the larger of the two slopes at min(s + h, 1).
    """
    h = 0.5 / 255.0
    s = np.clip(imageio.linear_to_srgb(np.clip(x, 0, 1)) + h, 0.0, 1.0)
    slope = np.maximum(1.0 / 12.92, 2.4 / 1.055 * ((s + 0.055) / 1.055) ** 1.4)
    return slope * h + 1e-7  # + float32 rounding of the decoded value


def test_png_round_trip_within_srgb_quantisation(tmp_path):
    img = _random_image(4, 16, 16)
    img[0, :, :] = np.linspace(0.0, 1.0, 16)[:, None]
    img[1, :4] = [[-0.5] * 3, [2.0] * 3, [1e-5] * 3, [0.0031308] * 3]
    path = tmp_path / "b.png"
    write_image(path, img)
    back = read_image(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    clamped = np.clip(img, 0.0, 1.0)
    err = np.abs(back.astype(np.float64) - clamped)
    assert np.all(err <= _png_bound(clamped))
    assert err.max() <= 2.4 / 1.055 * 0.5 / 255 + 1e-7  # the global bound, ~4.46e-3


def test_png_is_8bit_rgb_with_expected_codes(tmp_path):
    from PIL import Image

    img = np.array([[[0.0, 0.5, 1.0], [0.0031308, 4.0, -3.0]]], np.float32)
    write_image(tmp_path / "p.png", img)
    with Image.open(tmp_path / "p.png") as im:
        assert im.mode == "RGB" and im.size == (2, 1)
        assert np.asarray(im).tolist() == [[[0, 188, 255], [10, 255, 0]]]


# --- errors and atomicity ------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["out.jpg", "out", "out.exr.bak", "out.hdr"])
def test_unknown_extension(tmp_path, name):
    with pytest.raises(ImageIOError) as e:
        write_image(tmp_path / name, _random_image())
    msg = str(e.value)
    assert name in msg and ".exr" in msg and ".png" in msg and "\n" not in msg
    assert _listing(tmp_path) == []
    with pytest.raises(ImageIOError):
        read_image(tmp_path / name)


def test_image_io_error_is_a_pathtracer_error():
    assert issubclass(ImageIOError, PathtracerError)


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (0, 4, 3)])
def test_bad_shape(tmp_path, shape):
    with pytest.raises(ImageIOError, match="shape"):
        write_image(tmp_path / "s.exr", np.zeros(shape, np.float32))
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("ext", [".exr", ".png"])
def test_missing_directory(tmp_path, ext):
    target = tmp_path / "nope" / f"x{ext}"
    with pytest.raises(ImageIOError) as e:
        write_image(target, _random_image())
    msg = str(e.value)
    assert str(target) in msg and "No such file or directory" in msg and "\n" not in msg
    assert _listing(tmp_path) == []


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root ignores permissions")
def test_read_only_directory(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    try:
        with pytest.raises(ImageIOError, match="Permission denied"):
            write_image(d / "x.exr", _random_image())
        assert _listing(d) == []
    finally:
        d.chmod(0o755)


def test_permission_denied_names_path_and_reason(tmp_path, monkeypatch):
    real_open = os.open

    def deny(path, *args, **kwargs):
        if os.path.dirname(os.fspath(path)) == str(tmp_path):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(imageio.os, "open", deny)
    with pytest.raises(ImageIOError) as e:
        write_image(tmp_path / "x.png", _random_image())
    assert str(e.value) == f"{tmp_path / 'x.png'}: cannot write: Permission denied"
    assert _listing(tmp_path) == []


def test_target_is_a_directory(tmp_path):
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(ImageIOError, match="dir.png"):
        write_image(tmp_path / "dir.png", _random_image())
    assert _listing(tmp_path) == ["dir.png"]  # the temp file was removed


def _failing_writer(exc: BaseException):
    def writer(path, image):
        with open(path, "wb") as f:  # half a file, then the failure
            f.write(b"\x76\x2f\x31\x01partial")
        raise exc

    return writer


@pytest.mark.parametrize("ext,encoder", [(".exr", "_write_exr"), (".png", "_write_png")])
@pytest.mark.parametrize("exc", [RuntimeError("encoder exploded"), OSError(28, "No space left on device")])
def test_failure_while_writing_keeps_previous_file(tmp_path, monkeypatch, ext, encoder, exc):
    target = tmp_path / f"img{ext}"
    old = _random_image(5)
    write_image(target, old)
    before = target.read_bytes()
    monkeypatch.setattr(imageio, encoder, _failing_writer(exc))
    with pytest.raises(ImageIOError) as e:
        write_image(target, _random_image(6))
    assert str(target) in str(e.value) and "\n" not in str(e.value)
    assert target.read_bytes() == before
    assert _listing(tmp_path) == [target.name]


@pytest.mark.parametrize("ext,encoder", [(".exr", "_write_exr"), (".png", "_write_png")])
def test_keyboard_interrupt_while_writing_leaves_nothing(tmp_path, monkeypatch, ext, encoder):
    monkeypatch.setattr(imageio, encoder, _failing_writer(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        write_image(tmp_path / f"new{ext}", _random_image())
    assert _listing(tmp_path) == []


def test_overwrite_replaces_existing_file(tmp_path):
    target = tmp_path / "o.exr"
    write_image(target, _random_image(7))
    new = _random_image(8)
    write_image(target, new)
    assert np.array_equal(read_image(target), new)
    assert _listing(tmp_path) == ["o.exr"]


@pytest.mark.parametrize("name,content", [("missing.exr", None), ("junk.exr", b"not an exr"), ("junk.png", b"not a png")])
def test_read_errors(tmp_path, name, content):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ImageIOError) as e:
        read_image(path)
    assert name in str(e.value) and "\n" not in str(e.value)


def test_read_grayscale_and_rgba_png(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((2, 3), 188, np.uint8), "L").save(tmp_path / "g.png")
    Image.fromarray(np.full((2, 3, 4), 255, np.uint8), "RGBA").save(tmp_path / "a.png")
    g = read_image(tmp_path / "g.png")
    assert g.shape == (2, 3, 3) and np.allclose(g, srgb_to_linear(np.uint8(188)))
    a = read_image(tmp_path / "a.png")
    assert a.shape == (2, 3, 3) and np.allclose(a, 1.0)


def test_display_colours_are_stored_without_the_srgb_curve(tmp_path):
    """Debug views (0.5 n + 0.5) are display colours: the PNG holds round(255 v), as the seed shows them."""
    from PIL import Image

    v = np.linspace(0.0, 1.0, 256, dtype=np.float32)
    img = np.stack([v, v[::-1], np.full_like(v, 0.5)], axis=-1)[None]
    path = tmp_path / "debug.png"
    imageio.write_image(path, img, display=True)
    got = np.asarray(Image.open(path)).astype(int)
    np.testing.assert_array_equal(got[0], np.floor(img[0] * 255 + 0.5).astype(int))
    imageio.write_image(tmp_path / "debug.exr", img, display=True)  # EXR keeps the values as given
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "debug.exr"), img)


def test_layers_round_trip_in_exr_channels(tmp_path):
    """Layers go beside R, G, B as <name>.X/.Y/.Z (Mitsuba's moment output layout) and come back equal."""
    import OpenEXR

    rng = np.random.default_rng(3)
    img = rng.random((5, 7, 3), dtype=np.float32)
    layers = {"path": rng.random((5, 7, 3), dtype=np.float32), "m2_path": rng.random((5, 7, 3), dtype=np.float32)}
    p = tmp_path / "m.exr"
    write_image(p, img, layers=layers)
    with OpenEXR.File(str(p), separate_channels=True) as f:
        names = set(f.channels())
    assert names == {"R", "G", "B", "path.X", "path.Y", "path.Z", "m2_path.X", "m2_path.Y", "m2_path.Z"}
    back = imageio.read_layers(p)
    assert sorted(back) == sorted(layers)
    for k in layers:
        np.testing.assert_array_equal(back[k], layers[k])
    np.testing.assert_array_equal(read_image(p), img)
    assert imageio.read_layers(tmp_path / "m.exr") and not imageio.read_layers(_plain(tmp_path, img))


def _plain(tmp_path, img):
    p = tmp_path / "plain.exr"
    write_image(p, img)
    return p


def test_layers_need_exr_and_the_image_shape(tmp_path):
    img = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(ImageIOError, match=r"need an \.exr file"):
        write_image(tmp_path / "a.png", img, layers={"x": img})
    with pytest.raises(ImageIOError, match="layer 'x' has shape"):
        write_image(tmp_path / "a.exr", img, layers={"x": np.zeros((4, 5, 3))})
    assert not list(tmp_path.iterdir())  # nothing left behind


HDR = Path(__file__).parent / "data" / "hdr"


@pytest.mark.parametrize("name", ["rle_16x9", "flat_5x3"])
def test_radiance_hdr_reads_as_mitsuba_reads_it(name):
    """Files Mitsuba wrote, against what Mitsuba's reader gives for them: bit for bit (zeros, runs, literals)."""
    ours = read_image(HDR / f"{name}.hdr")
    expected = np.load(HDR / f"{name}.npy")
    assert ours.dtype == np.float32 and ours.shape == expected.shape
    assert np.array_equal(ours, expected)


def test_bad_radiance_hdr_files_are_one_line_errors(tmp_path):
    good = (HDR / "rle_16x9.hdr").read_bytes()
    cases = {
        "truncated.hdr": (good[:-40], "truncated scanline"),
        "noheader.hdr": (b"P6\n" + good[6:], "no #? header"),
        "xyze.hdr": (good.replace(b"32-bit_rle_rgbe", b"32-bit_rle_xyze"), "only FORMAT=32-bit_rle_rgbe"),
        "flipped.hdr": (good.replace(b"-Y 9 +X 16", b"+Y 9 +X 16"), "only the standard orientation"),
        "noresolution.hdr": (b"#?RGBE\nFORMAT=32-bit_rle_rgbe\n\n", "no resolution line"),
    }
    for fname, (data, why) in cases.items():
        p = tmp_path / fname
        p.write_bytes(data)
        with pytest.raises(ImageIOError) as e:
            read_image(p)
        msg = str(e.value)
        assert why in msg and "\n" not in msg and msg.startswith(str(p)), msg
