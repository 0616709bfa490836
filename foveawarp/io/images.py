"""Texture images and HDR environment maps -> linear float32 arrays on the host.

- :func:`load_image`: a PNG, JPEG or WebP file, or its encoded bytes (glTF's GLB buffer views and ``data:`` URIs),
  -> ``(H, W, 4)`` float32 RGBA in LINEAR values. ``srgb=True`` (base colour, emissive) decodes the RGB channels
  with the exact sRGB EOTF (IEC 61966-2-1, :func:`srgb_to_linear`); alpha is always linear. ``srgb=False`` (normal,
  metallic-roughness, occlusion) only scales the codes to [0, 1]. Grey, grey + alpha and RGB are expanded to RGBA
  (grey to all three colour channels, a missing alpha to 1); palette images through their palette (and its
  transparency), CMYK and YCbCr JPEGs to RGB. Decoding goes through Pillow (imageio's image backend), which reads
  16-bit RGB and RGBA PNGs at 8 bits per channel: such a file loads with a warning; 16-bit grey keeps 16 bits.
  The EXIF orientation tag is not applied (glTF textures are addressed as stored).
- :func:`load_environment`: a Radiance ``.hdr`` (RGBE, flat or run-length encoded; read here, see
  :func:`decode_radiance_hdr`) or an OpenEXR ``.exr`` (read with the ``OpenEXR`` module of the ``openexr``
  package when it is installed) -> ``(H, W, 3)`` float32 linear radiance.

Row 0 of every array is the top of the image, column 0 its left edge: glTF's UV (0, 0) is the top-left corner,
u to the right, v down (``foveawarp.textures`` samples with that convention).

Every failure (missing file, unknown extension, corrupt or truncated data, an unsupported layout, NaN/Inf in an
HDR image) raises ``ValueError`` naming the image and what was wrong.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..config import check_bool, check_choice, show

__all__ = [
    "IMAGE_EXTENSIONS",
    "ENVIRONMENT_EXTENSIONS",
    "IMAGE_MIME_TYPES",
    "srgb_to_linear",
    "load_image",
    "load_environment",
    "decode_radiance_hdr",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp")
ENVIRONMENT_EXTENSIONS = (".hdr", ".exr")
IMAGE_MIME_TYPES = ("image/png", "image/jpeg", "image/webp")

_FORMAT_BY_EXTENSION = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".webp": "webp"}
_FORMAT_BY_MIME = {"image/png": "png", "image/jpeg": "jpeg", "image/webp": "webp"}
_PIL_FORMAT = {"png": "PNG", "jpeg": "JPEG", "webp": "WEBP"}


def srgb_to_linear(x) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1) of encoded values ``x`` in [0, 1], computed in float64.

    ``x / 12.92`` for ``x <= 0.04045``, ``((x + 0.055) / 1.055) ** 2.4`` above.
    """
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


# the 256 8-bit codes decoded once
_SRGB_LUT8 = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)


def _sniff(data: bytes) -> Optional[str]:
    """The encoded format from the first bytes, or None."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    if data[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if len(data) >= 12 and data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "webp"
    return None


def _image_label(source, name) -> str:
    if name is not None:
        return str(name)
    if isinstance(source, (str, Path)):
        return str(source)
    return "<image bytes>"


def _read_source_bytes(source, label: str, extensions) -> tuple:
    """(bytes, suffix or None) of a path or bytes ``source``; missing files and unknown extensions raise."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source), None
    if not isinstance(source, (str, Path)):
        raise ValueError(f"image source must be a path (str or Path) or bytes, got {show(source)}")
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix not in extensions:
        raise ValueError(f"image {label!r}: extension must be one of {list(extensions)}, got {path.suffix!r}")
    if not path.is_file():
        raise ValueError(f"image {label!r}: file not found ({path})")
    try:
        return path.read_bytes(), suffix
    except OSError as e:
        raise ValueError(f"image {label!r}: cannot be read ({e})") from None


def _codes_to_unit(a: np.ndarray, label: str) -> np.ndarray:
    """Integer (or bool) codes -> float64 in [0, 1]: 8-bit / 255, 16-bit / 65535."""
    if a.dtype == np.bool_:
        return a.astype(np.float64)
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float64) / 65535.0
    if a.dtype.kind in "iu" and a.size and a.min() >= 0 and a.max() <= 65535:
        # 16-bit greyscale PNGs may arrive as 32-bit integers holding 16-bit codes
        return a.astype(np.float64) / 65535.0
    raise ValueError(f"image {label!r}: pixel type must be 8- or 16-bit unsigned codes, got {a.dtype}")


# Pillow modes read as they are (their arrays are grey, grey + alpha, RGB or RGBA codes); others are converted
_DIRECT_MODES = ("1", "L", "LA", "RGB", "RGBA", "I;16", "I;16L", "I;16B", "I")
_CONVERT_MODES = {"CMYK": "RGB", "YCbCr": "RGB", "LAB": "RGB", "HSV": "RGB", "La": "LA", "RGBa": "RGBA",
                  "RGBX": "RGB", "PA": "RGBA"}


def _decode_pillow(data: bytes, fmt: str, label: str) -> np.ndarray:
    """The first frame of encoded ``data`` as an array of grey, grey + alpha, RGB or RGBA codes."""
    from PIL import Image

    mode = None
    try:
        with Image.open(io.BytesIO(data), formats=[_PIL_FORMAT[fmt]]) as im:
            im.load()
            mode = im.mode
            if mode == "P":  # through the palette, keeping a transparent entry as alpha
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif mode in _CONVERT_MODES:
                im = im.convert(_CONVERT_MODES[mode])
            a = np.asarray(im) if mode == "P" or mode in _CONVERT_MODES or mode in _DIRECT_MODES else None
    except Exception as e:  # Pillow raises OSError, SyntaxError, EOFError, ValueError ... on corrupt data
        raise ValueError(f"image {label!r}: corrupt or unreadable {fmt.upper()} data ({type(e).__name__}: {e})") \
            from None
    if a is None:
        raise ValueError(f"image {label!r}: pixel mode must be grey, grey + alpha, palette, RGB, RGBA or CMYK, got "
                         f"Pillow mode {mode!r}")
    # PNG header: bit depth at byte 24, colour type at byte 25 (2 = RGB, 6 = RGBA)
    if fmt == "png" and len(data) > 25 and data[24] == 16 and data[25] in (2, 6):
        warnings.warn(f"image {label!r}: a 16-bit {'RGBA' if data[25] == 6 else 'RGB'} PNG is decoded at 8 bits "
                      "per channel (Pillow's PNG reader)", stacklevel=3)
    return a


def load_image(source: Union[str, Path, bytes], *, srgb: bool, name: Optional[str] = None,
               mime_type: Optional[str] = None) -> np.ndarray:
    """Decode a PNG, JPEG or WebP image to ``(H, W, 4)`` float32 linear RGBA (row 0 = the image's top).

    Args:
        source: a file path (extension one of :data:`IMAGE_EXTENSIONS`) or the encoded bytes.
        srgb: True for colour data stored sRGB-encoded (glTF base colour and emissive): RGB go through the sRGB
            EOTF, alpha stays linear. False for data textures (normal, metallic-roughness, occlusion): the codes
            are only scaled to [0, 1].
        name: the image's name in error messages (default: the path, or "<image bytes>").
        mime_type: with bytes, optionally the declared type, one of :data:`IMAGE_MIME_TYPES`. The format is
            always taken from the bytes' signature; a declared type is only checked to be a supported one.

    Raises:
        ValueError: not a path or bytes, missing file, unknown extension, bytes of no supported format, a
            corrupt or truncated image, an unsupported pixel type or channel count.
    """
    srgb = check_bool("srgb", srgb)
    label = _image_label(source, name)
    if mime_type is not None:
        check_choice(f"image {label!r} mime_type", mime_type, IMAGE_MIME_TYPES)
    data, suffix = _read_source_bytes(source, label, IMAGE_EXTENSIONS)
    fmt = _sniff(data)
    if fmt is None:
        what = f"a {_FORMAT_BY_EXTENSION[suffix].upper()} file" if suffix else "PNG, JPEG or WebP bytes"
        raise ValueError(f"image {label!r}: not {what} (unrecognized signature {data[:8]!r}, {len(data)} bytes)")
    a = _decode_pillow(data, fmt, label)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"image {label!r}: shape must be (H, W) or (H, W, 1..4) with H, W >= 1, got {a.shape}")
    h, w, c = a.shape
    color_codes = a[:, :, :3] if c >= 3 else a[:, :, :1]
    if srgb and a.dtype == np.uint8:
        color = _SRGB_LUT8[color_codes]  # exact per code
    else:
        color = _codes_to_unit(color_codes, label)
        if srgb:
            color = srgb_to_linear(color)
    out = np.empty((h, w, 4), dtype=np.float32)
    out[:, :, :3] = color  # a grey channel broadcasts to R, G and B
    out[:, :, 3] = _codes_to_unit(a[:, :, c - 1], label) if c in (2, 4) else 1.0
    return out


# ---------------------------------------------------------------------------------------------------------------
# HDR environment maps


def load_environment(path: Union[str, Path]) -> np.ndarray:
    """Read an HDR environment map (``.hdr`` Radiance RGBE or ``.exr`` OpenEXR) as ``(H, W, 3)`` float32 linear
    radiance, row 0 at the top.

    Negative values (possible in EXR half/float data) are raised to 0: radiance is not negative. The Radiance
    header's ``EXPOSURE`` is not applied (the stored values are taken as the radiance, as most renderers do).

    Raises:
        ValueError: missing file, extension not in :data:`ENVIRONMENT_EXTENSIONS`, corrupt or truncated data,
            unsupported layout, NaN or Inf in the pixels, ``.exr`` without the ``openexr`` package.
    """
    label = str(path)
    data, suffix = _read_source_bytes(path, label, ENVIRONMENT_EXTENSIONS)
    if suffix == ".hdr":
        rgb = decode_radiance_hdr(data, name=label)
    else:
        rgb = _decode_exr(data, label)
    bad = ~np.isfinite(rgb)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"environment {label!r}: pixels must be finite, got {show(rgb[idx])} at (row, column, "
                         f"channel) {idx}")
    return np.maximum(rgb, 0.0).astype(np.float32, copy=False)


def _decode_exr(data: bytes, label: str) -> np.ndarray:
    if data[:4] != b"\x76\x2f\x31\x01":
        raise ValueError(f"environment {label!r}: not an OpenEXR file (signature {data[:4]!r})")
    try:
        import OpenEXR
    except ImportError:
        raise ValueError(f"environment {label!r}: reading .exr needs the 'openexr' package (pip install openexr), "
                         "which is not installed; a Radiance .hdr is read without it") from None
    try:
        with OpenEXR.File(io.BytesIO(data)) as f:
            channels = f.channels()
            if "RGB" in channels:
                px = np.asarray(channels["RGB"].pixels)
            elif "RGBA" in channels:
                px = np.asarray(channels["RGBA"].pixels)[..., :3]
            elif all(k in channels for k in ("R", "G", "B")):
                px = np.stack([np.asarray(channels[k].pixels) for k in ("R", "G", "B")], axis=-1)
            elif "Y" in channels:
                px = np.repeat(np.asarray(channels["Y"].pixels)[..., None], 3, axis=-1)
            else:
                raise ValueError(f"environment {label!r}: needs R, G, B (or Y) channels, has {sorted(channels)}")
    except ValueError:
        raise
    except Exception as e:  # the bindings raise RuntimeError / OSError on corrupt files
        raise ValueError(f"environment {label!r}: corrupt or unreadable OpenEXR data ({type(e).__name__}: {e})") \
            from None
    if px.ndim != 3 or px.shape[2] != 3 or px.dtype.kind != "f":
        raise ValueError(f"environment {label!r}: expected (H, W, 3) floating-point pixels, got {px.shape} "
                         f"{px.dtype}")
    return px.astype(np.float32)


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE -> (..., 3) float32 with Radiance's ``colr_color``: ``(m + 0.5) * 2^(e - 136)``, 0 for
    ``e == 0``."""
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e == 0, 0.0, np.ldexp(1.0, e - 136))
    return ((rgbe[..., :3].astype(np.float64) + 0.5) * scale[..., None]).astype(np.float32)


def _hdr_fail(label: str, what: str):
    raise ValueError(f"environment {label!r}: {what}")


def _decode_scanline(buf: bytes, pos: int, width: int, prev: Optional[bytes], label: str, line: int) -> tuple:
    """One scanline of ``width`` RGBE pixels starting at ``buf[pos]`` -> (bytes of width * 4, next position)."""
    n = len(buf)
    if 8 <= width < 32768 and pos + 4 <= n and buf[pos] == 2 and buf[pos + 1] == 2 and buf[pos + 2] < 128:
        # adaptive run-length encoding: the four components one after the other, each as runs and literals
        if (buf[pos + 2] << 8 | buf[pos + 3]) != width:
            _hdr_fail(label, f"scanline {line}: run-length header says width {buf[pos + 2] << 8 | buf[pos + 3]}, "
                             f"the image is {width} wide")
        pos += 4
        comps = []
        for c in range(4):
            parts = []
            filled = 0
            while filled < width:
                if pos >= n:
                    _hdr_fail(label, f"truncated data in scanline {line}")
                count = buf[pos]
                if count > 128:
                    count -= 128
                    if pos + 1 >= n:
                        _hdr_fail(label, f"truncated data in scanline {line}")
                    parts.append(bytes((buf[pos + 1],)) * count)
                    pos += 2
                else:
                    if count == 0 or pos + 1 + count > n:
                        _hdr_fail(label, f"corrupt run-length data in scanline {line}, component {c}")
                    parts.append(buf[pos + 1:pos + 1 + count])
                    pos += 1 + count
                filled += count
                if filled > width:
                    _hdr_fail(label, f"run-length data overruns scanline {line} (component {c})")
            comps.append(np.frombuffer(b"".join(parts), dtype=np.uint8))
        return np.stack(comps, axis=1).tobytes(), pos
    # flat pixels, possibly with the original format's repeat records (1, 1, 1, count << shift)
    out = bytearray()
    got = 0
    shift = 0
    while got < width:
        if pos + 4 > n:
            _hdr_fail(label, f"truncated data in scanline {line}")
        px = buf[pos:pos + 4]
        pos += 4
        if px[0] == 1 and px[1] == 1 and px[2] == 1:
            last = out[-4:] if out else (prev[-4:] if prev else None)
            if last is None:
                _hdr_fail(label, f"scanline {line} starts with a repeat record")
            count = px[3] << shift
            if got + count > width:
                _hdr_fail(label, f"repeat record overruns scanline {line}")
            out += bytes(last) * count
            got += count
            shift += 8
        else:
            out += px
            got += 1
            shift = 0
    return bytes(out), pos


def decode_radiance_hdr(data: bytes, *, name: str = "<hdr bytes>") -> np.ndarray:
    """Decode a Radiance RGBE picture (``.hdr``/``.pic``) -> ``(H, W, 3)`` float32, row 0 at the top.

    Reads the header (``#?RADIANCE`` or ``#?RGBE`` magic, ``FORMAT=32-bit_rle_rgbe``), any of the eight resolution
    orders (``-Y H +X W`` is the common one; the others are flipped / transposed to it) and scanlines that are flat,
    in the original repeat-record encoding, or in the adaptive run-length encoding. The float of a pixel is
    Radiance's ``(mantissa + 0.5) * 2^(exponent - 136)`` (0 where the exponent byte is 0).
    """
    label = name
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValueError(f"environment {label!r}: data must be bytes, got {show(data)}")
    buf = bytes(data)
    if not (buf.startswith(b"#?RADIANCE") or buf.startswith(b"#?RGBE")):
        _hdr_fail(label, f"not a Radiance .hdr file (signature {buf[:10]!r}, expected b'#?RADIANCE')")
    end = buf.find(b"\n\n")
    if end < 0:
        _hdr_fail(label, "truncated header (no blank line ends it)")
    for line in buf[:end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT="):
            fmt = line[len(b"FORMAT="):].strip()
            if fmt != b"32-bit_rle_rgbe":
                _hdr_fail(label, f"FORMAT must be 32-bit_rle_rgbe, got {fmt.decode('latin-1')!r}")
    res_end = buf.find(b"\n", end + 2)
    if res_end < 0:
        _hdr_fail(label, "truncated header (no resolution line)")
    tokens = buf[end + 2:res_end].split()
    try:
        (s0, n0, s1, n1) = [t.decode("ascii") for t in tokens]
        n0, n1 = int(n0), int(n1)
    except (ValueError, UnicodeDecodeError):
        _hdr_fail(label, f"resolution line must be like '-Y 512 +X 1024', got {buf[end + 2:res_end][:40]!r}")
    axes = (s0[-1:], s1[-1:])
    if (len(s0) != 2 or len(s1) != 2 or s0[0] not in "+-" or s1[0] not in "+-" or set(axes) != {"X", "Y"}
            or n0 < 1 or n1 < 1):
        _hdr_fail(label, f"resolution line must be like '-Y 512 +X 1024', got {' '.join((s0, str(n0), s1, str(n1)))!r}")
    if n0 * n1 > (1 << 28):
        _hdr_fail(label, f"image of {n0} x {n1} pixels is larger than 2^28 pixels")
    pos = res_end + 1
    lines = []
    prev = None
    for i in range(n0):
        row, pos = _decode_scanline(buf, pos, n1, prev, label, i)
        lines.append(row)
        prev = row
    rgbe = np.frombuffer(b"".join(lines), dtype=np.uint8).reshape(n0, n1, 4)
    if axes[0] == "X":  # scanlines are columns: make them rows
        rgbe = rgbe.transpose(1, 0, 2)
        sx, sy = s0[0], s1[0]
    else:
        sy, sx = s0[0], s1[0]
    if sy == "+":  # +Y: the first row stored is the bottom one
        rgbe = rgbe[::-1]
    if sx == "-":  # -X: right to left
        rgbe = rgbe[:, ::-1]
    return _rgbe_to_float(np.ascontiguousarray(rgbe))
