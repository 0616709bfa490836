"""foveawarp.io.images: texture images decoded to linear RGBA, and HDR environment maps.

References written here: the sRGB EOTF formula, PNG/JPEG/WebP files encoded with Pillow, and Radiance .hdr files
built byte by byte by an RGBE encoder of this file (Radiance's setcolr rounding, flat and run-length scanlines).
"""

import io
import math

import numpy as np
import pytest
from PIL import Image

from foveawarp.io.images import decode_radiance_hdr, load_environment, load_image, srgb_to_linear


def _srgb_eotf(c):
    """IEC 61966-2-1, one code value at a time in float64."""
    x = c / 255.0
    return x / 12.92 if x <= 0.04045 else ((x + 0.055) / 1.055) ** 2.4


def _png(array, mode=None):
    buf = io.BytesIO()
    Image.fromarray(array, mode=mode).save(buf, format="PNG")
    return buf.getvalue()


def _encode(img, fmt, **kw):
    buf = io.BytesIO()
    img.save(buf, format=fmt, **kw)
    return buf.getvalue()


# --------------------------------------------------------------------------------------------------------------
# 8/16-bit images


def test_srgb_decode_all_256_codes():
    codes = np.arange(256, dtype=np.uint8)
    rgb = np.stack([codes, codes[::-1], codes], axis=-1).reshape(1, 256, 3)
    out = load_image(_png(rgb), srgb=True)
    expect = np.array([_srgb_eotf(c) for c in range(256)])
    assert out.shape == (1, 256, 4) and out.dtype == np.float32
    np.testing.assert_allclose(out[0, :, 0], expect, rtol=0, atol=1e-7)
    np.testing.assert_allclose(out[0, :, 1], expect[::-1], rtol=0, atol=1e-7)
    np.testing.assert_array_equal(out[0, :, 3], 1.0)
    lin = load_image(_png(rgb), srgb=False)
    np.testing.assert_allclose(lin[0, :, 0], np.arange(256) / 255.0, rtol=0, atol=1e-7)
    # the vectorized function agrees with the scalar formula, including both sides of the 0.04045 knee
    np.testing.assert_allclose(srgb_to_linear(np.arange(256) / 255.0), expect, rtol=1e-12)


def test_sixteen_bit_png():
    codes = np.array([[0, 1000, 2651, 32768, 65535]], dtype=np.uint16)
    lin = load_image(_png(codes), srgb=False)
    np.testing.assert_allclose(lin[0, :, 0], codes[0] / 65535.0, rtol=0, atol=1e-7)
    dec = load_image(_png(codes), srgb=True)
    x = codes[0] / 65535.0
    expect = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(dec[0, :, 0], expect, rtol=0, atol=1e-7)


def test_channel_expansion_and_linear_alpha():
    grey = np.array([[10, 200]], dtype=np.uint8)
    la = np.array([[[10, 51], [200, 255]]], dtype=np.uint8)
    rgba = np.array([[[255, 0, 10, 51]]], dtype=np.uint8)
    g = load_image(_png(grey), srgb=True)
    np.testing.assert_allclose(g[0, :, :3], [[_srgb_eotf(10)] * 3, [_srgb_eotf(200)] * 3], atol=1e-7)
    np.testing.assert_array_equal(g[..., 3], 1.0)
    a = load_image(_png(la, "LA"), srgb=True)
    np.testing.assert_allclose(a[0, 0], [_srgb_eotf(10)] * 3 + [51 / 255.0], atol=1e-7)
    np.testing.assert_allclose(a[0, 1, 3], 1.0)
    c = load_image(_png(rgba), srgb=True)
    np.testing.assert_allclose(c[0, 0], [1.0, 0.0, _srgb_eotf(10), 51 / 255.0], atol=1e-7)  # alpha not decoded
    p = Image.fromarray(np.array([[0, 1]], dtype=np.uint8), mode="L").convert("P")
    assert load_image(_encode(p, "PNG"), srgb=False).shape == (1, 2, 4)


def test_orientation_row_zero_is_top(tmp_path):
    checker = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)
    path = tmp_path / "checker.png"
    path.write_bytes(_png(checker))
    img = load_image(path, srgb=False)
    np.testing.assert_array_equal(img[0, 0, :3], [1, 0, 0])  # top-left
    np.testing.assert_array_equal(img[0, 1, :3], [0, 1, 0])  # top-right
    np.testing.assert_array_equal(img[1, 0, :3], [0, 0, 1])  # bottom-left
    np.testing.assert_array_equal(img[1, 1, :3], [1, 1, 1])
    np.testing.assert_array_equal(load_image(str(path), srgb=False), img)
    np.testing.assert_array_equal(load_image(path.read_bytes(), srgb=False, mime_type="image/png"), img)


def test_jpeg_and_webp_from_bytes_and_file(tmp_path):
    flat = Image.new("RGB", (16, 8), (200, 100, 50))
    jpg = _encode(flat, "JPEG", quality=95)
    out = load_image(jpg, srgb=True, mime_type="image/jpeg")
    assert out.shape == (8, 16, 4)
    for ch, code in enumerate((200, 100, 50)):
        lo, hi = _srgb_eotf(code - 3), _srgb_eotf(code + 3)  # JPEG is lossy: a few codes
        assert lo <= out[..., ch].min() and out[..., ch].max() <= hi
    (tmp_path / "a.jpeg").write_bytes(jpg)
    np.testing.assert_array_equal(load_image(tmp_path / "a.jpeg", srgb=True), out)
    webp = _encode(flat, "WEBP", lossless=True)
    w = load_image(webp, srgb=False)
    np.testing.assert_allclose(w[0, 0, :3], [200 / 255.0, 100 / 255.0, 50 / 255.0], atol=1e-7)


def test_palette_and_cmyk_modes():
    # palette with a transparent entry -> RGBA through the palette; CMYK JPEG -> RGB (not read as RGBA)
    p = Image.new("P", (2, 1))
    p.putpalette([255, 0, 0, 0, 255, 0])
    p.putpixel((1, 0), 1)
    out = load_image(_encode(p, "PNG", transparency=0), srgb=False)
    np.testing.assert_array_equal(out[0], [[1, 0, 0, 0], [0, 1, 0, 1]])
    out = load_image(_encode(p, "PNG"), srgb=False)
    np.testing.assert_array_equal(out[0, :, 3], 1.0)
    cmyk = Image.new("CMYK", (8, 8), (0, 255, 0, 0))  # no cyan, full magenta: RGB (255, 0, 255)
    out = load_image(_encode(cmyk, "JPEG", quality=100), srgb=False)
    np.testing.assert_allclose(out[4, 4], [1.0, 0.0, 1.0, 1.0], atol=3 / 255.0)


def _png16_rgb(codes):
    """A 16-bit RGB PNG built by hand (Pillow cannot write one): filter byte 0 on every row."""
    import struct
    import zlib

    def chunk(kind, payload):
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    h, w, _ = codes.shape
    raw = b"".join(b"\x00" + codes[y].astype(">u2").tobytes() for y in range(h))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_sixteen_bit_rgb_png_warns():
    codes = np.array([[[1000, 2000, 65535], [300, 40000, 5]]], dtype=np.uint16)
    with pytest.warns(UserWarning, match="rgb16.*16-bit RGB PNG is decoded at 8 bits"):
        out = load_image(_png16_rgb(codes), srgb=False, name="rgb16")
    # each channel is the high byte of its code: within 1/255 of the 16-bit value
    np.testing.assert_allclose(out[..., :3], codes / 65535.0, atol=1 / 255.0)


def test_corrupt_files_named(tmp_path):
    jpg = _encode(Image.new("RGB", (32, 32), (9, 99, 199)), "JPEG")
    (tmp_path / "cut.jpg").write_bytes(jpg[: len(jpg) // 2])
    with pytest.raises(ValueError, match=r"cut\.jpg.*corrupt or unreadable JPEG"):
        load_image(tmp_path / "cut.jpg", srgb=True)
    webp = _encode(Image.new("RGB", (32, 32), (9, 99, 199)), "WEBP")
    (tmp_path / "cut.webp").write_bytes(webp[:30])
    with pytest.raises(ValueError, match=r"cut\.webp.*corrupt or unreadable WEBP"):
        load_image(tmp_path / "cut.webp", srgb=True)
    # a JPEG under a .png name is read by its signature, not its extension
    (tmp_path / "really_jpeg.png").write_bytes(jpg)
    assert load_image(tmp_path / "really_jpeg.png", srgb=False).shape == (32, 32, 4)
    (tmp_path / "text.hdr").write_bytes(b"not an hdr")
    with pytest.raises(ValueError, match=r"text\.hdr.*not a Radiance"):
        load_environment(tmp_path / "text.hdr")
    with pytest.raises(ValueError, match=r"sub.*file not found"):
        load_environment(tmp_path / "sub.hdr")


def test_image_errors(tmp_path):
    with pytest.raises(ValueError, match="missing.png.*not found"):
        load_image(tmp_path / "missing.png", srgb=True)
    (tmp_path / "a.tga").write_bytes(b"xx")
    with pytest.raises(ValueError, match=r"a\.tga.*extension must be one of"):
        load_image(tmp_path / "a.tga", srgb=True)
    (tmp_path / "text.png").write_bytes(b"this is not an image")
    with pytest.raises(ValueError, match="text.png.*not a PNG file"):
        load_image(tmp_path / "text.png", srgb=True)
    good = _png(np.zeros((4, 4, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="tex7.*corrupt or unreadable PNG"):
        load_image(good[: len(good) // 2], srgb=True, name="tex7")
    with pytest.raises(ValueError, match="not PNG, JPEG or WebP bytes"):
        load_image(b"", srgb=False)
    with pytest.raises(ValueError, match="mime_type must be one of"):
        load_image(good, srgb=False, mime_type="image/gif")
    with pytest.raises(ValueError, match="srgb must be True or False"):
        load_image(good, srgb="yes")
    with pytest.raises(ValueError, match="path .* or bytes"):
        load_image(12, srgb=True)


# --------------------------------------------------------------------------------------------------------------
# Radiance .hdr


def _to_rgbe(rgb):
    """Radiance's setcolr: mantissas ``c * frexp(max)[0] * 256 / max``, truncated; exponent byte ``e + 128``."""
    out = np.zeros(rgb.shape[:-1] + (4,), dtype=np.uint8)
    for idx in np.ndindex(rgb.shape[:-1]):
        c = rgb[idx]
        m = float(max(c))
        if m <= 1e-32:
            continue
        f, e = math.frexp(m)
        scale = f * 255.9999 / m
        out[idx] = [int(c[0] * scale), int(c[1] * scale), int(c[2] * scale), e + 128]
    return out


def _rgbe_value(px):
    """Radiance's colr_color of one RGBE pixel."""
    if px[3] == 0:
        return np.zeros(3)
    return (px[:3].astype(np.float64) + 0.5) * 2.0 ** (int(px[3]) - 136)


def _rle_component(values):
    """Adaptive RLE of one component: runs (count + 128, value) of 3 or more, literals (count, bytes) of up to 128."""
    out = bytearray()
    i, n = 0, len(values)
    while i < n:
        j = i
        while j < n and values[j] == values[i] and j - i < 127:
            j += 1
        if j - i >= 3:
            out += bytes((128 + j - i, values[i]))
            i = j
            continue
        start = i
        while i < n and i - start < 128:
            if i + 2 < n and values[i] == values[i + 1] == values[i + 2]:
                break
            i += 1
        out += bytes((i - start,)) + bytes(values[start:i])
    return bytes(out)


def _hdr_file(rgbe_rows, res_line, rle):
    """Header + the stored scanlines (``rgbe_rows``: (n0, n1, 4) uint8 in stored order)."""
    out = bytearray(b"#?RADIANCE\n# built by the test\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n")
    out += res_line.encode() + b"\n"
    for row in rgbe_rows:
        if rle:
            w = row.shape[0]
            out += bytes((2, 2, w >> 8, w & 255))
            for c in range(4):
                out += _rle_component(list(row[:, c]))
        else:
            out += row.tobytes()
    return bytes(out)


@pytest.mark.parametrize("rle", [False, True])
def test_hdr_roundtrip_against_encoder(tmp_path, rng, rle):
    h, w = 5, 19
    rgb = rng.uniform(0.0, 50.0, (h, w, 3)) * (rng.uniform(size=(h, w, 1)) ** 4)
    rgb[0, :10] = [0.25, 0.5, 1.0]  # a run
    rgb[2, 3] = 0.0
    rgbe = _to_rgbe(rgb)
    path = tmp_path / "env.hdr"
    path.write_bytes(_hdr_file(rgbe, f"-Y {h} +X {w}", rle))
    env = load_environment(path)
    assert env.shape == (h, w, 3) and env.dtype == np.float32
    expect = np.array([[_rgbe_value(rgbe[y, x]) for x in range(w)] for y in range(h)])
    np.testing.assert_allclose(env, expect, rtol=1e-6, atol=0)
    # RGBE keeps 8 bits of mantissa relative to the largest component
    err = np.abs(env - rgb).max(axis=-1)
    assert np.all(err <= rgb.max(axis=-1) / 128.0 + 1e-30)
    np.testing.assert_array_equal(env[2, 3], 0.0)


def test_hdr_hand_built_bytes():
    px = bytes((128, 64, 0, 129, 0, 0, 0, 0, 255, 255, 255, 128))
    data = b"#?RGBE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 3\n" + px
    env = decode_radiance_hdr(data)
    np.testing.assert_allclose(env[0], [[128.5 / 128, 64.5 / 128, 0.5 / 128], [0, 0, 0],
                                        [255.5 / 256, 255.5 / 256, 255.5 / 256]], rtol=1e-7)
    # original repeat records: (1, 1, 1, n) repeats the previous pixel n times, shifts by 8 when consecutive
    data = b"#?RADIANCE\n\n-Y 1 +X 4\n" + bytes((10, 20, 30, 130, 1, 1, 1, 3))
    env = decode_radiance_hdr(data)
    np.testing.assert_allclose(env[0], np.tile([10.5 / 64, 20.5 / 64, 30.5 / 64], (4, 1)), rtol=1e-7)


@pytest.mark.parametrize("res", ["-Y 3 +X 8", "+Y 3 +X 8", "-Y 3 -X 8", "+Y 3 -X 8",
                                 "+X 8 -Y 3", "+X 8 +Y 3", "-X 8 -Y 3", "-X 8 +Y 3"])
def test_hdr_orientations(res):
    h, w = 3, 8
    rgbe = np.zeros((h, w, 4), dtype=np.uint8)
    rgbe[..., 0] = np.arange(h * w).reshape(h, w)  # a distinct code per pixel, row 0 = top
    rgbe[..., 3] = 136
    t = res.split()
    stored = rgbe
    if t[1] == str(w):  # X is the scanline (slow) axis: each stored scanline is a column
        sx, sy = t[0][0], t[2][0]
        stored = stored.transpose(1, 0, 2)
        if sx == "-":
            stored = stored[::-1]
        if sy == "+":
            stored = stored[:, ::-1]
    else:
        sy, sx = t[0][0], t[2][0]
        if sy == "+":
            stored = stored[::-1]
        if sx == "-":
            stored = stored[:, ::-1]
    env = decode_radiance_hdr(_hdr_file(np.ascontiguousarray(stored), res, rle=False))
    np.testing.assert_allclose(env[..., 0], np.arange(h * w).reshape(h, w) + 0.5)


def test_hdr_errors(tmp_path):
    ok = _hdr_file(_to_rgbe(np.ones((2, 9, 3))), "-Y 2 +X 9", rle=True)
    decode_radiance_hdr(ok)
    with pytest.raises(ValueError, match="truncated"):
        decode_radiance_hdr(ok[:-5])
    with pytest.raises(ValueError, match="not a Radiance"):
        decode_radiance_hdr(b"P6\n1 1\n255\n\x00\x00\x00")
    with pytest.raises(ValueError, match="FORMAT must be 32-bit_rle_rgbe"):
        decode_radiance_hdr(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\x01\x01\x01\x80")
    with pytest.raises(ValueError, match="resolution line"):
        decode_radiance_hdr(b"#?RADIANCE\n\n-Y 1 +Z 1\n\x01\x01\x01\x80")
    with pytest.raises(ValueError, match="resolution line"):
        decode_radiance_hdr(b"#?RADIANCE\n\n-Y one +X 1\n\x01\x01\x01\x80")
    with pytest.raises(ValueError, match="starts with a repeat record"):
        decode_radiance_hdr(b"#?RADIANCE\n\n-Y 1 +X 2\n\x01\x01\x01\x02")
    with pytest.raises(ValueError, match="missing.hdr.*not found"):
        load_environment(tmp_path / "missing.hdr")
    (tmp_path / "env.png").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"env\.png.*extension must be one of \['\.hdr', '\.exr'\]"):
        load_environment(tmp_path / "env.png")


def test_environment_nan_and_inf_refused(tmp_path, monkeypatch):
    # RGBE cannot encode NaN or Inf: the check is exercised through a decoder returning them
    import foveawarp.io.images as images

    (tmp_path / "bad.hdr").write_bytes(b"#?RADIANCE\n\n-Y 1 +X 1\n\x01\x02\x03\x80")
    for bad in (np.nan, np.inf):
        monkeypatch.setattr(images, "decode_radiance_hdr",
                            lambda data, name, v=bad: np.array([[[0.0, v, 0.0]]], dtype=np.float32))
        with pytest.raises(ValueError, match=r"bad.hdr.*must be finite.*\(0, 0, 1\)"):
            images.load_environment(tmp_path / "bad.hdr")


# --------------------------------------------------------------------------------------------------------------
# OpenEXR


def test_exr_signature_checked(tmp_path):
    # imageio without an EXR plugin writes a TIFF under an .exr name: that is refused, not misread
    (tmp_path / "fake.exr").write_bytes(b"II*\x00" + bytes(64))
    with pytest.raises(ValueError, match="fake.exr.*not an OpenEXR file"):
        load_environment(tmp_path / "fake.exr")


def test_exr_without_openexr_names_the_package(tmp_path):
    try:
        import OpenEXR  # noqa: F401
    except ImportError:
        (tmp_path / "a.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(64))
        with pytest.raises(ValueError, match="a.exr.*openexr"):
            load_environment(tmp_path / "a.exr")
    else:
        pytest.skip("the openexr package is installed")


def test_exr_read(tmp_path, rng):
    OpenEXR = pytest.importorskip("OpenEXR")
    rgb = rng.uniform(0.0, 20.0, (6, 9, 3)).astype(np.float32)
    rgb[1, 2, 0] = -0.5
    path = tmp_path / "env.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": rgb}) as f:
        f.write(str(path))
    env = load_environment(path)
    np.testing.assert_array_equal(env, np.maximum(rgb, 0.0))
    rgb[3, 3, 1] = np.nan
    with OpenEXR.File(header, {"RGB": rgb}) as f:
        f.write(str(path))
    with pytest.raises(ValueError, match=r"env.exr.*must be finite.*\(3, 3, 1\)"):
        load_environment(path)
