"""Reading and writing images: linear float32 OpenEXR and 8-bit sRGB PNG.

Writes are atomic: the image goes to a hidden temporary file in the target's directory, which is
renamed over the target only once complete, so an error or Ctrl-C never leaves a partial file behind
and never damages an existing one.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Mapping

import numpy as np

from pathtracer.errors import ImageIOError

SUPPORTED_EXTENSIONS = (".exr", ".png")  # what we write
# what we read: JPEG textures (decoded as PNG is) and Radiance RGBE (.hdr) maps, as Mitsuba reads them
READ_EXTENSIONS = SUPPORTED_EXTENSIONS + (".jpg", ".jpeg", ".hdr", ".rgbe")
LAYER_CHANNELS = "XYZ"
RGB_LAYERS = ("stderr",)  # layers of RGB values (channels <name>.R, .G, .B); the others are XYZ, as Mitsuba's


def _extension(path: str | os.PathLike, allowed: tuple = SUPPORTED_EXTENSIONS) -> str:
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in allowed:
        shown = ext if ext else "no extension"
        raise ImageIOError(
            f"{os.fspath(path)}: unsupported image format ({shown}); supported: "
            + ", ".join(allowed)
        )
    return ext


def _reason(exc: BaseException) -> str:
    """A one-line reason for an OS or library error."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


# --- sRGB ---------------------------------------------------------------------------------------


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The exact sRGB OETF on [0, 1] (float64): 12.92 x below 0.0031308, else 1.055 x^(1/2.4) - 0.055."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_to_linear(s: np.ndarray) -> np.ndarray:
    """Inverse sRGB (EOTF) to linear float32. Integer input is read as 8-bit codes (0..255)."""
    s = np.asarray(s)
    if np.issubdtype(s.dtype, np.integer):
        s = s.astype(np.float64) / 255.0
    s = np.asarray(s, dtype=np.float64)
    lin = np.where(s <= 0.04045, s / 12.92, np.power((np.maximum(s, 0.04045) + 0.055) / 1.055, 2.4))
    return lin.astype(np.float32)


def to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB at exposure 1: clamp to [0, 1] (NaN -> 0), OETF, round to nearest."""
    x = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    return np.floor(linear_to_srgb(x) * 255.0 + 0.5).astype(np.uint8)


# --- encoders (module-level so tests can replace them) -------------------------------------------


def _write_exr(path: str, image: np.ndarray, layers: Mapping[str, np.ndarray] | None = None) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    # One "RGB" entry of shape (H, W, 3) is stored as the three standard channels R, G, B.
    channels = {"RGB": image}
    for name, layer in (layers or {}).items():  # Mitsuba's layout: channels <layer>.X, <layer>.Y, <layer>.Z
        if layer.ndim == 2:  # one value per pixel: a channel of its own
            channels[name] = np.ascontiguousarray(layer)
            continue
        for c, axis in zip("RGB" if name in RGB_LAYERS else LAYER_CHANNELS, range(3)):
            channels[f"{name}.{c}"] = np.ascontiguousarray(layer[..., axis])
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def _write_png(path: str, image: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(to_srgb8(image), "RGB").save(path, format="PNG")


# --- public API ---------------------------------------------------------------------------------


def write_image(path: str | os.PathLike, image: np.ndarray, *, display: bool = False,
                layers: Mapping[str, np.ndarray] | None = None) -> None:
    """Write an (H, W, 3) linear image: ``.exr`` as float32 RGB, ``.png`` as 8-bit sRGB.

    ``layers`` (EXR only): more (H, W, 3) float32 images, stored as channels ``<name>.X``, ``.Y``, ``.Z`` beside
    R, G, B (as Mitsuba writes its moment integrator's layers; ``<name>.R``, ``.G``, ``.B`` for the RGB_LAYERS), or
    (H, W) ones, stored as one channel ``<name>``; ``read_layers`` reads them back.

    ``display=True`` says the values are already display colours (the debug views' 0.5 v + 0.5, as the seed
    shows them): a PNG then stores them without the sRGB curve. EXR always stores the values as given.

    Raises ImageIOError (one line naming the path) for an unsupported extension, a bad array or
    a file that cannot be written; the target is then left as it was.
    """
    path = os.fspath(path)
    ext = _extension(path)
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        raise ImageIOError(f"{path}: cannot write: expected an (H, W, 3) image, got shape {image.shape}")
    image = np.ascontiguousarray(image, dtype=np.float32)
    if layers:
        if ext != ".exr":
            raise ImageIOError(f"{path}: cannot write: image layers ({', '.join(layers)}) need an .exr file")
        layers = {k: np.asarray(v, dtype=np.float32) for k, v in layers.items()}
        for k, v in layers.items():
            if v.shape != image.shape and v.shape != image.shape[:2]:
                raise ImageIOError(f"{path}: cannot write: layer {k!r} has shape {v.shape}, the image {image.shape}")
    if display and ext == ".png":
        image = srgb_to_linear(np.clip(image, 0.0, 1.0))  # the PNG encoder's sRGB curve then gives them back

    directory, name = os.path.split(os.path.abspath(path))
    tmp = os.path.join(directory, f".{name}.{secrets.token_hex(4)}.tmp{ext}")
    try:
        # O_EXCL: never clobber someone else's file; mode 0o666 lets the umask apply as for open().
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except OSError as e:
        raise ImageIOError(f"{path}: cannot write: {_reason(e)}") from None
    try:
        if layers:
            _write_exr(tmp, image, layers)
        else:
            (_write_exr if ext == ".exr" else _write_png)(tmp, image)
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.remove(tmp)
        except OSError:
            pass
        if isinstance(e, (OSError, RuntimeError, ValueError)):
            raise ImageIOError(f"{path}: cannot write: {_reason(e)}") from None
        raise


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as linear float32 (H, W, 3): EXR and Radiance HDR as stored, PNG and JPEG decoded through
    inverse sRGB."""
    path = os.fspath(path)
    ext = _extension(path, READ_EXTENSIONS)
    try:
        with open(path, "rb"):  # a clean OS reason (and no C-library noise) for missing files
            pass
    except OSError as e:
        raise ImageIOError(f"{path}: cannot read: {_reason(e)}") from None
    try:
        if ext in (".hdr", ".rgbe"):
            return _read_rgbe(path)
        return _read_exr(path) if ext == ".exr" else _read_png(path)
    except ImageIOError:
        raise
    except Exception as e:  # library errors on corrupt files
        raise ImageIOError(f"{path}: cannot read: {_reason(e)}") from None


def read_layers(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The extra layers of an EXR file by name: channels ``<name>.X``, ``.Y``, ``.Z`` (or ``.R``, ``.G``, ``.B``)
    as float32 (H, W, 3), single channels other than R, G, B, A, Y as (H, W)."""
    import OpenEXR

    path = os.fspath(path)
    try:
        with OpenEXR.File(path, separate_channels=True) as f:
            channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as e:
        raise ImageIOError(f"{path}: cannot read: {_reason(e)}") from None
    out = {}
    for n in sorted({k.rsplit(".", 1)[0] for k in channels if "." in k}):
        for letters in (LAYER_CHANNELS, "RGB"):
            if all(f"{n}.{c}" in channels for c in letters):
                out[n] = np.stack([channels[f"{n}.{c}"].astype(np.float32) for c in letters], axis=-1)
    for k, v in channels.items():
        if "." not in k and k not in ("R", "G", "B", "A", "Y"):
            out[k] = v.astype(np.float32)
    return out


def _read_exr(path: str) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(path, separate_channels=True) as f:
        channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    if all(c in channels for c in "RGB"):
        planes = [channels[c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ImageIOError(f"{path}: cannot read: no R, G, B (or Y) channels, found {sorted(channels)}")
    return np.stack([p.astype(np.float32) for p in planes], axis=-1)


def _read_rgbe(path: str) -> np.ndarray:
    """Radiance RGBE, as Mitsuba 3.9 reads it (src/core/bitmap.cpp: read_rgbe): a "#?" first line, FORMAT
    32-bit_rle_rgbe, EXPOSURE and other header lines ignored, the "-Y H +X W" orientation only; scanlines run-length
    encoded per channel (2, 2, width) or flat RGBE pixels; a pixel is (r, g, b) * 2^(e - 136), or 0 where e = 0."""
    with open(path, "rb") as f:
        data = f.read()

    def bad(why: str):
        return ImageIOError(f"{path}: cannot read: not a Radiance HDR file ({why})")

    if not data.startswith(b"#?"):
        raise bad("no #? header")
    pos, fmt, size = data.find(b"\n") + 1, None, None
    while size is None:
        end = data.find(b"\n", pos)
        if pos <= 0 or end < 0:
            raise bad("no resolution line")
        line = data[pos:end].decode("latin-1").strip()
        pos = end + 1
        if line.startswith("FORMAT="):
            fmt = line[7:]
        tokens = line.split()
        if len(tokens) == 4 and tokens[0] in ("-Y", "+Y") and tokens[2] in ("+X", "-X"):
            if (tokens[0], tokens[2]) != ("-Y", "+X"):
                raise ImageIOError(f"{path}: cannot read: only the standard orientation -Y H +X W is supported "
                                   f"(got {line})")
            try:
                size = (int(tokens[1]), int(tokens[3]))
            except ValueError:
                raise bad(f"resolution {line!r}") from None
    if fmt != "32-bit_rle_rgbe":
        raise ImageIOError(f"{path}: cannot read: only FORMAT=32-bit_rle_rgbe is supported (got "
                           f"{fmt or 'no FORMAT line'})")
    h, w = size
    if h <= 0 or w <= 0:
        raise bad(f"{w} x {h} pixels")
    body = np.frombuffer(data, dtype=np.uint8, offset=pos)
    rgbe = np.empty((h, w, 4), dtype=np.uint8)
    flat = w < 8 or w > 0x7FFF or not (len(body) >= 4 and body[0] == 2 and body[1] == 2 and not body[2] & 0x80)
    if flat:
        if len(body) < h * w * 4:
            raise bad("truncated pixels")
        rgbe[:] = body[: h * w * 4].reshape(h, w, 4)
    else:
        i = 0
        for y in range(h):
            if i + 4 > len(body) or body[i] != 2 or body[i + 1] != 2 or (int(body[i + 2]) << 8 | body[i + 3]) != w:
                raise bad(f"scanline {y} is not a run-length encoded scanline of width {w}")
            i += 4
            for c in range(4):
                x = 0
                row = rgbe[y, :, c]
                while x < w:
                    if i + 2 > len(body):
                        raise bad("truncated scanline")
                    count = int(body[i])
                    if count > 128:  # a run of one value
                        count -= 128
                        if count > w - x:
                            raise bad("bad scanline data")
                        row[x:x + count] = body[i + 1]
                        i += 2
                    else:  # count literal values
                        if count == 0 or count > w - x:
                            raise bad("bad scanline data")
                        if i + 1 + count > len(body):
                            raise bad("truncated scanline")
                        row[x:x + count] = body[i + 1:i + 1 + count]
                        i += 1 + count
                    x += count
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(np.float32(1.0), e - 136), np.float32(0.0)).astype(np.float32)
    return (rgbe[..., :3].astype(np.float32) * scale[..., None]).astype(np.float32)


def _read_png(path: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        if im.mode in ("I;16", "I;16B", "I;16L", "I"):
            s = np.asarray(im, dtype=np.float64) / 65535.0
            s = np.repeat(s[..., None], 3, axis=-1)
        else:
            s = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    return srgb_to_linear(s)
