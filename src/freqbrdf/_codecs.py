"""The image codecs neither Pillow nor OpenEXR provide: 16-bit PNG and Radiance RGBE (``.hdr``).

Private to `freqbrdf.images`, which reads and writes images through them: Pillow decodes 16-bit
colour PNGs at 8 bits, and no dependency reads or writes Radiance's run-length encoded RGBE. The
byte-level loops are numba kernels.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numba
import numpy as np

from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path

# --- 16-bit PNG -----------------------------------------------------------------------------------


def _png_header(path: Path) -> tuple[int, int, int]:
    """Return a PNG's bit depth, colour type and interlace method (0, 0, 0 where the header is not a PNG's)."""
    with open(path, "rb") as file:
        head = file.read(33)
    if len(head) < 33 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return 0, 0, 0
    return head[24], head[25], head[28]


# Channels of a PNG by colour type: grey, RGB, grey + alpha, RGBA (type 3, a palette, has no 16-bit form).
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def _read_png16(path: Path) -> np.ndarray:
    """Read a 16-bit PNG (H, W, C) float32 in [0, 1]: Pillow reads 16-bit colour as 8 bits."""
    _, colour, interlace = _png_header(path)
    if colour not in _PNG_CHANNELS:
        raise InputError(path, f"not a readable PNG image (colour type {colour} at 16 bits)")
    if interlace:
        raise InputError(path, "is an interlaced 16-bit PNG, which is not supported: save it without interlacing")
    data = path.read_bytes()
    position, chunks, width, height = 8, [], 0, 0
    while position + 8 <= len(data):
        length = int.from_bytes(data[position:position + 4], "big")
        kind, body = data[position + 4:position + 8], data[position + 8:position + 8 + length]
        position += 12 + length
        if kind == b"IHDR":
            width, height = int.from_bytes(body[:4], "big"), int.from_bytes(body[4:8], "big")
        elif kind == b"IDAT":
            chunks.append(body)
        elif kind == b"IEND":
            break
    channels = _PNG_CHANNELS[colour]
    stride = width * channels * 2
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(chunks)), np.uint8)
        rows = raw[: height * (stride + 1)].reshape(height, stride + 1)
    except (zlib.error, ValueError) as err:
        raise InputError(path, f"not a readable PNG image ({err})") from None
    if not width or not height or np.any(rows[:, 0] > 4):
        raise InputError(path, "not a readable PNG image (bad filter types)")
    unfiltered = np.empty((height, stride), np.uint8)
    _png_unfilter(rows, unfiltered, channels * 2)
    return (unfiltered.view(">u2").reshape(height, width, channels).astype(np.float32) / np.float32(65535.0))


@numba.njit(cache=True)
def _png_unfilter(rows, out, step):
    """Undo PNG's per-row filters (none, sub, up, average, Paeth) of ``rows`` (H, 1 + S) into ``out`` (H, S)."""
    height, stride = out.shape
    for y in range(height):
        kind = rows[y, 0]
        for i in range(stride):
            value = np.int32(rows[y, 1 + i])
            left = np.int32(out[y, i - step]) if i >= step else np.int32(0)
            up = np.int32(out[y - 1, i]) if y > 0 else np.int32(0)
            corner = np.int32(out[y - 1, i - step]) if y > 0 and i >= step else np.int32(0)
            if kind == 1:
                value += left
            elif kind == 2:
                value += up
            elif kind == 3:
                value += (left + up) // 2
            elif kind == 4:
                estimate = left + up - corner
                distance_left, distance_up, distance_corner = abs(estimate - left), abs(estimate - up), abs(estimate - corner)
                if distance_left <= distance_up and distance_left <= distance_corner:
                    value += left
                elif distance_up <= distance_corner:
                    value += up
                else:
                    value += corner
            out[y, i] = value & 255


# --- Radiance RGBE (.hdr) -------------------------------------------------------------------------

_RGBE_RESOLUTION = re.compile(rb"-Y (\d+) \+X (\d+)")
_MIN_RUN = 4  # shorter repeats are cheaper as literals


def _read_rgbe(path: Path) -> np.ndarray:
    data = path.read_bytes()
    if not data.startswith(b"#?"):
        raise InputError(path, "not a Radiance HDR file (missing '#?' signature)")
    header_end = data.find(b"\n\n")
    if header_end < 0:
        raise InputError(path, "truncated Radiance HDR header")
    exposure = 1.0
    for line in data[:header_end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            raise InputError(path, f"unsupported pixel format {line[7:].decode(errors='replace')}")
        if line.startswith(b"EXPOSURE="):  # stored values were multiplied by each EXPOSURE
            try:
                exposure *= float(line[9:])
            except ValueError:
                problem = f"bad header line {line.decode(errors='replace')!r}"
                raise InputError(path, problem) from None
    if not exposure > 0:
        raise InputError(path, f"EXPOSURE must be positive, got {exposure}")
    line_end = data.find(b"\n", header_end + 2)
    match = _RGBE_RESOLUTION.fullmatch(data[header_end + 2 : line_end].strip())
    if line_end < 0 or match is None:
        raise InputError(path, "unsupported Radiance HDR orientation (only '-Y H +X W')")
    height, width = int(match[1]), int(match[2])
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    end = _decode_rgbe(np.frombuffer(data, dtype=np.uint8), line_end + 1, rgbe)
    if end < 0:
        raise InputError(path, "corrupt or truncated Radiance HDR pixel data")
    # Radiance's colr_color: channel = (mantissa + 0.5) * 2^(exponent - 136); exponent 0 is black.
    exponent = rgbe[..., 3].astype(np.int32)
    scale = np.where(exponent > 0, np.ldexp(1.0, exponent - 136), 0.0) / exposure
    return ((rgbe[..., :3] + 0.5) * scale[..., None]).astype(np.float32)


@numba.njit(cache=True)
def _decode_rgbe(data, start, out):  # data (bytes,) uint8; out (H, W, 4) uint8
    """Decode flat or new-style run-length scanlines into ``out``; returns end offset or -1."""
    height, width = out.shape[0], out.shape[1]
    size = data.shape[0]
    pos = start
    for row in range(height):
        is_rle = (
            8 <= width < 32768
            and pos + 4 <= size
            and data[pos] == 2
            and data[pos + 1] == 2
            and data[pos + 2] < 128
        )
        if not is_rle:  # flat scanline: 4 bytes per pixel
            if pos + 4 * width > size:
                return -1
            for col in range(width):
                for channel in range(4):
                    out[row, col, channel] = data[pos + 4 * col + channel]
            pos += 4 * width
            continue
        if (np.int64(data[pos + 2]) << 8 | data[pos + 3]) != width:
            return -1
        pos += 4
        for channel in range(4):  # each channel of the scanline is run-length coded separately
            col = 0
            while col < width:
                if pos >= size:
                    return -1
                count = np.int64(data[pos])
                pos += 1
                if count > 128:  # a run: one byte repeated count - 128 times
                    count -= 128
                    if col + count > width or pos >= size:
                        return -1
                    for k in range(count):
                        out[row, col + k, channel] = data[pos]
                    pos += 1
                else:  # count literal bytes
                    if count == 0 or col + count > width or pos + count > size:
                        return -1
                    for k in range(count):
                        out[row, col + k, channel] = data[pos + k]
                    pos += count
                col += count
    return pos


@numba.njit(cache=True)
def _encode_rgbe_rle(rgbe, out):  # rgbe (H, W, 4) uint8; out (bytes,) uint8 large enough
    """New-style run-length encoding (as Radiance writes it); returns the number of bytes."""
    height, width = rgbe.shape[0], rgbe.shape[1]
    pos = 0
    for row in range(height):
        out[pos] = 2
        out[pos + 1] = 2
        out[pos + 2] = width >> 8
        out[pos + 3] = width & 255
        pos += 4
        for channel in range(4):
            values = rgbe[row, :, channel]
            cur = 0
            while cur < width:
                # find the next run of at least _MIN_RUN equal bytes, starting at run_start
                run_start = cur
                run_length = 0
                while run_start < width:
                    run_length = 1
                    while (
                        run_start + run_length < width
                        and run_length < 127
                        and values[run_start + run_length] == values[run_start]
                    ):
                        run_length += 1
                    if run_length >= _MIN_RUN:
                        break
                    run_start += run_length
                while cur < run_start:  # literals up to the run
                    count = min(run_start - cur, 128)
                    out[pos] = count
                    out[pos + 1 : pos + 1 + count] = values[cur : cur + count]
                    pos += 1 + count
                    cur += count
                if run_start < width:
                    out[pos] = 128 + run_length
                    out[pos + 1] = values[run_start]
                    pos += 2
                    cur = run_start + run_length
    return pos


def write_hdr(path: str | Path, image: np.ndarray) -> None:
    """Write linear radiance as run-length encoded Radiance RGBE, atomically.

    RGBE's shared exponent and 8-bit mantissas give a relative precision of about 1/256.

    Parameters
    ----------
    path : str or Path
        The ``.hdr`` file.
    image : (H, W, 3) array_like
        Linear radiance.

    Raises
    ------
    ValueError
        If ``image`` is not (H, W, 3) or has values outside [0, 2^127) (RGBE stores no others).
    """
    rgb = np.asarray(image, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_hdr needs an (H, W, 3) array, got shape {rgb.shape}")
    if not np.isfinite(rgb).all() or (rgb < 0).any() or rgb.max(initial=0.0) >= 2.0**127:
        raise ValueError("RGBE stores finite values in [0, 2^127) only")
    height, width = rgb.shape[:2]
    # Radiance's setcolr: a shared exponent from the brightest channel, mantissas in [0, 256).
    brightest = rgb.max(axis=2)
    fraction, exponent = np.frexp(brightest)
    visible = brightest > 1e-32
    scale = np.where(visible, fraction * 256.0 / np.where(visible, brightest, 1.0), 0.0)
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    rgbe[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255)
    rgbe[..., 3] = np.where(visible, exponent + 128, 0)
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n".encode()
    if 8 <= width < 32768:
        buffer = np.empty(height * (4 + 4 * (width + width // 128 + 1)), dtype=np.uint8)
        body = buffer[: _encode_rgbe_rle(rgbe, buffer)].tobytes()
    else:  # run-length coding is only defined for these widths
        body = rgbe.tobytes()
    with atomic_path(path) as tmp:
        tmp.write_bytes(header + body)
