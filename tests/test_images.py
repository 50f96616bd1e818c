"""Image I/O: EXR / Radiance HDR / PNG round trips, cross-checks, bad input, atomic writes."""

import warnings

import numpy as np
import OpenEXR
import pytest

from freqbrdf import __version__
from freqbrdf.errors import InputError
from freqbrdf.images import (
    REC709_CHROMATICITIES,
    CaptureDataWarning,
    clipped_channels,
    linear_to_srgb,
    read_image,
    read_mask,
    srgb_to_linear,
    write_exr,
    write_hdr,
    write_png,
)


def hdr_test_image(height=37, width=53, seed=0):
    """Radiance over five decades, with constant rows (long runs) and black pixels."""
    rng = np.random.default_rng(seed)
    radiance = (rng.random((height, width, 3)) ** 6 * 1e4).astype(np.float32)
    radiance[3:9] = 2.5
    radiance[10, :10] = 0.0
    return radiance


def exr_channels(path):
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return {name: channel.pixels for name, channel in exr.channels().items()}


# --- EXR -------------------------------------------------------------------------------------


def test_exr_float_rgb_round_trip_is_exact(tmp_path):
    radiance = hdr_test_image()
    write_exr(tmp_path / "a.exr", radiance)
    assert sorted(exr_channels(tmp_path / "a.exr")) == ["B", "G", "R"]
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == radiance.shape
    np.testing.assert_array_equal(back, radiance)


def test_exr_half_and_single_channel(tmp_path):
    grey = hdr_test_image()[..., 0].astype(np.float16)
    write_exr(tmp_path / "y.exr", grey[..., None])
    channels = exr_channels(tmp_path / "y.exr")
    assert list(channels) == ["Y"] and channels["Y"].dtype == np.float16
    back = read_image(tmp_path / "y.exr")
    assert back.shape == grey.shape + (3,)
    for channel in range(3):
        np.testing.assert_array_equal(back[..., channel], grey.astype(np.float32))


def exr_header(path):
    with OpenEXR.File(str(path), header_only=True) as exr:
        return dict(exr.parts[0].header)


def test_exr_header_carries_software_comments_and_chromaticities_and_no_time(tmp_path):
    radiance = hdr_test_image(12, 13)
    write_exr(tmp_path / "colour.exr", radiance, comments="a test colour map", chromaticities=REC709_CHROMATICITIES)
    header = exr_header(tmp_path / "colour.exr")
    assert header["software"] == f"freqbrdf {__version__}"
    assert header["comments"] == "a test colour map"
    # Rec.709 primaries, D65 white, as float32 (the attribute's precision).
    np.testing.assert_allclose(header["chromaticities"], (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290),
                               rtol=1e-6)
    assert not {"capDate", "utcOffset"} & set(header)
    # Without them: software only; same pixels and attributes, same bytes.
    write_exr(tmp_path / "plain.exr", radiance[..., 0])
    plain = exr_header(tmp_path / "plain.exr")
    assert plain["software"] == f"freqbrdf {__version__}"
    assert "chromaticities" not in plain and "comments" not in plain
    write_exr(tmp_path / "again.exr", radiance, comments="a test colour map", chromaticities=REC709_CHROMATICITIES)
    assert (tmp_path / "again.exr").read_bytes() == (tmp_path / "colour.exr").read_bytes()
    np.testing.assert_array_equal(read_image(tmp_path / "colour.exr"), radiance)
    with pytest.raises(ValueError, match="8 numbers"):
        write_exr(tmp_path / "bad.exr", radiance, chromaticities=(0.64, 0.33))


def test_exr_rgba_drops_alpha_and_single_grey_channel_is_grey(tmp_path):
    rng = np.random.default_rng(1)
    planes = {name: rng.random((6, 7)).astype(np.float32) for name in "RGBA"}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, dict(planes)) as exr:  # File() swaps in Channel objects
        exr.write(str(tmp_path / "rgba.exr"))
    back = read_image(tmp_path / "rgba.exr")
    np.testing.assert_array_equal(back, np.stack([planes[c] for c in "RGB"], axis=2))
    with OpenEXR.File(header, {"Y": planes["A"]}) as exr:
        exr.write(str(tmp_path / "y.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "y.exr")[..., 2], planes["A"])
    np.testing.assert_array_equal(read_mask(tmp_path / "rgba.exr"), planes["A"] > 0.5)


def test_an_exr_cropped_to_its_pixels_or_with_overscan_reads_as_its_frame(tmp_path):
    """A renderer's crop (data window inside the display window: Arnold's autocrop) is placed in its frame,
    zeros around it; overscan beyond the frame is dropped."""
    rng = np.random.default_rng(4)
    planes = {name: rng.random((4, 6)).astype(np.float32) for name in "RGBA"}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "dataWindow": ((2, 1), (7, 4)), "displayWindow": ((0, 0), (9, 7))}
    with OpenEXR.File(header, {name: plane.copy() for name, plane in planes.items()}) as exr:
        exr.write(str(tmp_path / "crop.exr"))
    image = read_image(tmp_path / "crop.exr")
    assert image.shape == (8, 10, 3)
    np.testing.assert_array_equal(image[1:5, 2:8], np.stack([planes[c] for c in "RGB"], axis=2))
    image[1:5, 2:8] = 0.0
    assert not image.any()
    mask = read_mask(tmp_path / "crop.exr")
    assert mask.shape == (8, 10) and mask.sum() == (planes["A"] > 0.5).sum() and not mask[0].any()
    header.update(dataWindow=((-1, -1), (4, 2)), displayWindow=((0, 0), (2, 1)))  # overscan of one pixel
    with OpenEXR.File(header, {name: plane.copy() for name, plane in planes.items()}) as exr:
        exr.write(str(tmp_path / "overscan.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "overscan.exr"),
                                  np.stack([planes[c][1:3, 1:4] for c in "RGB"], axis=2))


@pytest.mark.parametrize("channels", [("Z",), ("A",), ("depth.Z",), ("Z", "A")])
def test_exr_without_colour_channels_is_refused_as_radiance(tmp_path, channels):
    """A renderer's depth or alpha AOV saved in place of a photograph is refused, naming its channels."""
    plane = np.random.default_rng(2).random((6, 7)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {name: plane.copy() for name in channels}) as exr:
        exr.write(str(tmp_path / "aov.exr"))
    with pytest.raises(InputError, match="no colour channels") as caught:
        read_image(tmp_path / "aov.exr")
    message = str(caught.value)
    assert "aov.exr" in message and all(name in message for name in channels) and "\n" not in message
    if channels == ("A",):  # the same file still reads as a mask
        np.testing.assert_array_equal(read_mask(tmp_path / "aov.exr"), plane > 0.5)


def test_a_multi_layer_exr_is_read_as_its_beauty_pass(tmp_path):
    """Blender's multi-layer EXR: the Combined layer is the photograph; other colour layers alone are refused."""
    rng = np.random.default_rng(3)
    planes = {name: rng.random((5, 4)).astype(np.float32) for name in (
        "ViewLayer.Combined.R", "ViewLayer.Combined.G", "ViewLayer.Combined.B", "ViewLayer.Combined.A",
        "ViewLayer.DiffCol.R", "ViewLayer.DiffCol.G", "ViewLayer.DiffCol.B", "ViewLayer.Depth.Z")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {name: plane.copy() for name, plane in planes.items()}) as exr:
        exr.write(str(tmp_path / "render.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "render.exr"),
                                  np.stack([planes[f"ViewLayer.Combined.{c}"] for c in "RGB"], axis=2))
    np.testing.assert_array_equal(read_mask(tmp_path / "render.exr"), planes["ViewLayer.Combined.A"] > 0.5)
    others = {name: plane for name, plane in planes.items() if "Combined" not in name}
    others.update({f"ViewLayer.GlossCol.{c}": planes[f"ViewLayer.DiffCol.{c}"] for c in "RGB"})
    with OpenEXR.File(header, {name: plane.copy() for name, plane in others.items()}) as exr:
        exr.write(str(tmp_path / "passes.exr"))
    with pytest.raises(InputError, match="2 colour layers .*DiffCol.*GlossCol.*none is the beauty pass"):
        read_image(tmp_path / "passes.exr")


# --- Radiance HDR ------------------------------------------------------------------------------


@pytest.mark.parametrize("width", [53, 5])  # 5 < 8: written flat, not run-length encoded
def test_hdr_round_trip_within_rgbe_precision(tmp_path, width):
    radiance = hdr_test_image(width=width)
    write_hdr(tmp_path / "a.hdr", radiance)
    back = read_image(tmp_path / "a.hdr")
    assert back.shape == radiance.shape and back.dtype == np.float32
    # Shared exponent, 8-bit mantissas, centre-of-bin decoding: error <= 1/256 of the brightest
    # channel of the pixel.
    brightest = radiance.max(axis=2, keepdims=True)
    assert np.all(np.abs(back - radiance) <= brightest / 256 * 1.0001)
    assert np.all(back[10, :10] == 0)


def test_hdr_run_length_encoding_compresses_constant_rows(tmp_path):
    flat = np.full((16, 64, 3), 0.75, dtype=np.float32)
    write_hdr(tmp_path / "flat.hdr", flat)
    assert (tmp_path / "flat.hdr").stat().st_size < 16 * 64 * 4 / 10
    np.testing.assert_allclose(read_image(tmp_path / "flat.hdr"), flat, rtol=1 / 256)


def test_hdr_decodes_hand_made_run_length_scanline(tmp_path):
    # One 8-pixel scanline, each channel coded per the Radiance spec: R a run of 8 x 64,
    # G 8 literals, B a run of 4 then 4 literals, E a run of 8 x 129 (exponent 1).
    green = list(range(10, 90, 10))
    scanline = [2, 2, 0, 8, 128 + 8, 64, 8, *green, 128 + 4, 0, 4, 1, 2, 3, 4, 128 + 8, 129]
    (tmp_path / "hand.hdr").write_bytes(
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=2\n\n-Y 1 +X 8\n" + bytes(scanline)
    )
    expected_mantissas = np.stack([[64] * 8, green, [0, 0, 0, 0, 1, 2, 3, 4]], axis=1)
    expected = (expected_mantissas + 0.5) * 2.0 ** (129 - 136) / 2  # EXPOSURE divides out
    np.testing.assert_allclose(read_image(tmp_path / "hand.hdr")[0], expected, rtol=1e-6)


def test_hdr_agrees_with_mitsuba_bitmap(tmp_path):
    """An independent RGBE implementation (Mitsuba's) reads our files and writes ones we read."""
    import mitsuba as mi  # Bitmap I/O needs no variant

    radiance = hdr_test_image()
    brightest = radiance.max(axis=2, keepdims=True)
    write_hdr(tmp_path / "ours.hdr", radiance)
    # Mitsuba decodes without the half-bin offset: allow one full mantissa step.
    theirs = np.array(mi.Bitmap(str(tmp_path / "ours.hdr")))
    assert np.all(np.abs(theirs - radiance) <= brightest / 128 * 1.0001)
    mi.Bitmap(radiance).write(str(tmp_path / "mitsuba.hdr"))
    assert np.all(np.abs(read_image(tmp_path / "mitsuba.hdr") - radiance) <= brightest / 128)


# --- PNG / JPEG and sRGB --------------------------------------------------------------------------


def test_srgb_transfer_functions():
    linear = np.linspace(0, 1, 1001, dtype=np.float32)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(linear)), linear, atol=1e-6)
    # Reference points of IEC 61966-2-1 and continuity at the linear segment's end.
    np.testing.assert_allclose(linear_to_srgb(np.array([0.0, 0.18, 0.5, 1.0])),
                               [0.0, 0.46135613, 0.73535698, 1.0], atol=1e-6)
    below, above = srgb_to_linear(np.array([0.04045 - 1e-6, 0.04045 + 1e-6]))
    assert abs(above - below) < 1e-6
    assert np.all(np.diff(linear_to_srgb(linear)) > 0)


def test_png_round_trip_linearises_with_warning(tmp_path):
    linear = np.clip(hdr_test_image()[..., :3] / 1e4, 0, 1)
    write_png(tmp_path / "a.png", linear_to_srgb(linear))
    with pytest.warns(UserWarning, match=r"a\.png.*HDR"):
        back = read_image(tmp_path / "a.png")
    assert back.shape == linear.shape and back.dtype == np.float32
    quantised = np.round(linear_to_srgb(linear) * 255) / 255
    np.testing.assert_allclose(back, srgb_to_linear(quantised), atol=1e-6)


def test_grey_png_and_jpeg_read_as_rgb(tmp_path):
    from PIL import Image

    grey = np.tile(np.arange(0, 256, 4, dtype=np.uint8), (8, 1))
    Image.fromarray(grey).save(tmp_path / "g.png")
    Image.fromarray(np.stack([grey] * 3, axis=2)).save(tmp_path / "g.jpg", quality=95)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        png, jpeg = read_image(tmp_path / "g.png"), read_image(tmp_path / "g.jpg")
    assert png.shape == jpeg.shape == (8, 64, 3)
    np.testing.assert_allclose(png[..., 1], srgb_to_linear(grey / 255.0), atol=1e-6)
    np.testing.assert_allclose(jpeg, png, atol=0.03)  # JPEG is lossy


def test_read_mask_from_grey_and_alpha(tmp_path):
    from PIL import Image

    inside = np.zeros((10, 12), dtype=bool)
    inside[2:7, 3:9] = True
    Image.fromarray(np.where(inside, 255, 0).astype(np.uint8)).save(tmp_path / "m.png")
    np.testing.assert_array_equal(read_mask(tmp_path / "m.png"), inside)
    rgba = np.zeros((10, 12, 4), dtype=np.uint8)
    rgba[..., :3] = 255  # white everywhere: the alpha channel carries the mask
    rgba[..., 3] = np.where(inside, 255, 0)
    Image.fromarray(rgba).save(tmp_path / "cutout.png")
    np.testing.assert_array_equal(read_mask(tmp_path / "cutout.png"), inside)


# --- bad input ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["a.exr", "a.hdr", "a.png", "a.jpg"])
def test_missing_and_corrupt_files_raise_input_error(tmp_path, name):
    with pytest.raises(InputError, match=name.replace(".", r"\.") + ".*does not exist"):
        read_image(tmp_path / name)
    (tmp_path / name).write_bytes(b"#?RADIANCE\n" + bytes(range(256)) * 3)
    with pytest.raises(InputError, match=name.replace(".", r"\.")) as err:
        read_image(tmp_path / name)
    assert err.value.path == tmp_path / name


def test_truncated_files_raise_input_error(tmp_path):
    write_exr(tmp_path / "t.exr", hdr_test_image())
    write_hdr(tmp_path / "t.hdr", hdr_test_image())
    for path in (tmp_path / "t.exr", tmp_path / "t.hdr"):
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        with pytest.raises(InputError, match=path.name):
            read_image(path)


def test_unsupported_extension(tmp_path):
    (tmp_path / "a.tif").write_bytes(b"II*\0")
    with pytest.raises(InputError, match=r"a\.tif.*unsupported image type '\.tif'"):
        read_image(tmp_path / "a.tif")


def test_validate_reports_count_and_first_bad_pixel(tmp_path):
    radiance = np.ones((5, 6, 3), dtype=np.float32)
    radiance[1, 4, 2] = np.nan
    radiance[3, 0, 0] = np.inf
    radiance[2, 5, 1] = -0.5
    write_exr(tmp_path / "bad.exr", radiance)
    assert np.isnan(read_image(tmp_path / "bad.exr")[1, 4, 2])  # without validate: as stored
    with pytest.raises(InputError) as err:
        read_image(tmp_path / "bad.exr", validate=True)
    message = str(err.value)
    assert "bad.exr" in message
    assert "2 non-finite pixel(s), first at row 1, column 4" in message
    radiance[1, 4, 2] = radiance[3, 0, 0] = 1.0
    write_exr(tmp_path / "bad.exr", radiance)
    with pytest.raises(InputError, match=r"bad.exr: 1 negative pixel\(s\) down to -0.5, first at row 2, column 5: "
                                         r"deeper than the noise of an HDR merge"):
        read_image(tmp_path / "bad.exr", validate=True)


def test_negative_noise_of_an_hdr_merge_is_clamped_with_a_warning(tmp_path):
    radiance = np.full((5, 6, 3), 2.0, dtype=np.float32)
    radiance[2, 5, 1] = -0.004  # as real HDR merges have, near black
    radiance[4, 0, 0] = -0.001
    write_exr(tmp_path / "merged.exr", radiance)
    with pytest.warns(CaptureDataWarning, match=r"merged.exr: 2 slightly negative pixel\(s\) \(down to -0.004\) "
                                                r"clamped to 0"):
        image = read_image(tmp_path / "merged.exr", validate=True)
    assert image.min() == 0.0 and image[2, 5, 1] == 0.0 and image[0, 0, 0] == 2.0


# --- atomic writes -------------------------------------------------------------------------------


def test_failed_writes_leave_nothing_behind(tmp_path, monkeypatch):
    target = tmp_path / "out.exr"
    write_exr(target, np.zeros((4, 4, 3), np.float32))
    before = target.read_bytes()

    def broken_write(self, filename):
        open(filename, "wb").write(b"partial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(OpenEXR.File, "write", broken_write)
    with pytest.raises(RuntimeError, match="disk full"):
        write_exr(target, np.ones((4, 4, 3), np.float32))
    assert target.read_bytes() == before  # the old file survives intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]  # no temporary left

    with pytest.raises(ValueError):
        write_exr(tmp_path / "two.exr", np.zeros((4, 4, 2), np.float32))
    with pytest.raises(ValueError):
        write_hdr(tmp_path / "neg.hdr", -np.ones((4, 4, 3), np.float32))
    with pytest.raises(ValueError):
        write_png(tmp_path / "five.png", np.zeros((4, 4, 5), np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


def test_writers_create_parent_folders(tmp_path):
    write_png(tmp_path / "a" / "b" / "c.png", np.full((3, 3), 0.5))
    write_hdr(tmp_path / "d" / "e.hdr", np.ones((3, 9, 3)))
    assert (tmp_path / "a" / "b" / "c.png").is_file() and (tmp_path / "d" / "e.hdr").is_file()


def test_clipped_channels_mark_each_channels_plateau_not_an_hdr_peak():
    rng = np.random.default_rng(3)
    image = rng.random((20, 30, 3)).astype(np.float32) * 0.8
    assert not clipped_channels(image).any()  # HDR: one brightest pixel is no plateau
    image[5:8, 10:14, 0] = 1.0  # a blown highlight, red clipped at the sensor's ceiling
    image[0, 0, 0] = 1.0
    image[2:4, 2:4, 2] = 0.9  # blue clipped lower: white balance applied after the sensor
    found = clipped_channels(image)
    assert found[5:8, 10:14, 0].all() and found[0, 0, 0] and found[2:4, 2:4, 2].all()
    assert found[..., 0].sum() == 13 and found[..., 2].sum() == 4 and not found[..., 1].any()


# --- 16-bit PNG --------------------------------------------------------------------------------


def _png16(path, values: np.ndarray, colour_type: int) -> None:
    """Write ``values`` (H, W, C) uint16 as a 16-bit PNG, each row with the next of PNG's five filters."""
    import struct
    import zlib

    height, width, channels = values.shape
    step = 2 * channels
    raw = values.astype(">u2").view(np.uint8).reshape(height, width * step).astype(np.int32)
    lines = []
    for y in range(height):
        line, previous = raw[y], raw[y - 1] if y else np.zeros_like(raw[y])
        left = np.concatenate([np.zeros(step, np.int32), line[:-step]])
        corner = np.concatenate([np.zeros(step, np.int32), previous[:-step]])
        estimate = left + previous - corner
        paeth = np.where((np.abs(estimate - left) <= np.abs(estimate - previous))
                         & (np.abs(estimate - left) <= np.abs(estimate - corner)), left,
                         np.where(np.abs(estimate - previous) <= np.abs(estimate - corner), previous, corner))
        predictor = [np.zeros_like(line), left, previous, (left + previous) // 2, paeth][y % 5]
        lines.append(bytes([y % 5]) + ((line - predictor) % 256).astype(np.uint8).tobytes())

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 16, colour_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"".join(lines)))
                     + chunk(b"IEND", b""))


@pytest.mark.parametrize("channels, colour_type", [(3, 2), (4, 6)])
def test_a_16_bit_png_keeps_its_16_bits(tmp_path, channels, colour_type):
    """Pillow reads 16-bit colour PNGs as 8 bits; every filter type is undone exactly."""
    values = np.random.default_rng(5).integers(0, 65536, (11, 9, channels)).astype(np.uint16)
    _png16(tmp_path / "deep.png", values, colour_type)
    with pytest.warns(UserWarning, match="16-bit sRGB image linearised"):
        radiance = read_image(tmp_path / "deep.png")
    np.testing.assert_allclose(radiance, srgb_to_linear(values[..., :3] / 65535.0), rtol=0, atol=1e-6)
    if channels == 4:
        np.testing.assert_array_equal(read_mask(tmp_path / "deep.png"), values[..., 3] / 65535.0 > 0.5)


def test_a_16_bit_grey_png_written_by_pillow_reads_alike_both_ways(tmp_path):
    from PIL import Image

    from freqbrdf.images import _read_png16

    values = (np.arange(40 * 30).reshape(30, 40) * 53 % 65536).astype(np.uint16)
    Image.fromarray(values).save(tmp_path / "grey.png")
    np.testing.assert_array_equal(_read_png16(tmp_path / "grey.png")[..., 0], values / np.float32(65535.0))
