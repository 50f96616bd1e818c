"""Choose the fit folder's EXR compression and PNG level: write time and size of each.

A fit writes eight maps at T x T (three colour, five single-channel). This writes eight maps of
that shape, taken from the bundled photographic materials (`freqbrdf.assets`, coffee and
astronaut: base colour, roughness and metallic, and their smoothed copies as stand-ins for the std
and entropy maps) at T = 512, with each lossless compression that Blender and the Khronos tools
read (none, RLE, ZIPS, ZIP, PIZ), in turn, REPEATS times, and reads them back to check they are
lossless. Lossy compressions (PXR24 on float32, B44, DWA) and those that older OpenEXR cannot read
(ZSTD, HTJ2K) are left out. `freqbrdf.images.write_exr` uses the one these figures choose
(docs/results.md#speed). The same maps as the 8-bit pictures a fit writes beside them (sRGB colour,
a colour map for the scalars) are written as PNG at each zlib level of `PNG_LEVELS`:
`freqbrdf.images.PNG_COMPRESS_LEVEL` is the fastest within 20 % of the smallest.

    python benchmarks/timing/bench_exr.py

Prints the figures and saves benchmarks/results/bench_exr.json.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR
from matplotlib import colormaps
from PIL import Image
from scipy import ndimage

from freqbrdf.assets import material_dir
from freqbrdf.images import linear_to_srgb, read_image
from freqbrdf.model.materials import load_material_maps, resize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common
from _common import control_seconds, machine, save_results  # noqa: E402

TEXTURE_RES = 512
REPEATS = 5
COMPRESSIONS = ("NO", "RLE", "ZIPS", "ZIP", "PIZ")
PNG_LEVELS = (1, 3, 6, 9)


def fit_like_maps() -> dict[str, np.ndarray]:
    """Eight float32 maps at T x T: three (T, T, 3), five (T, T)."""
    coffee = resize(load_material_maps(material_dir("coffee")), TEXTURE_RES)
    astronaut = resize(load_material_maps(material_dir("astronaut")), TEXTURE_RES)
    smooth = lambda image: ndimage.gaussian_filter(image, 2.0).astype(np.float32)  # noqa: E731
    return {"base_color": coffee.base_color, "base_color_std": smooth(astronaut.base_color),
            "roughness": coffee.roughness, "metallic": coffee.metallic, "roughness_std": smooth(astronaut.roughness),
            "metallic_std": smooth(astronaut.metallic), "entropy": smooth(coffee.roughness),
            "trust": (astronaut.roughness > 0.5).astype(np.float32)}


def write_all(maps: dict[str, np.ndarray], folder: Path, compression) -> None:
    for name, image in maps.items():
        planes = ({"Y": np.ascontiguousarray(image, np.float32)} if image.ndim == 2 else
                  {channel: np.ascontiguousarray(image[..., index], np.float32) for index, channel in enumerate("RGB")})
        with OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage}, planes) as exr:
            exr.write(str(folder / f"{name}.exr"))


def pictures(maps: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The maps as the 8-bit pictures a fit writes: sRGB for colour, magma for the scalars."""
    def quantised(values: np.ndarray) -> np.ndarray:
        return np.round(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)
    return {name: quantised(linear_to_srgb(image) if image.ndim == 3 else colormaps["magma"](image)[..., :3])
            for name, image in maps.items()}


def png_levels(maps: dict[str, np.ndarray], scratch: Path) -> dict:
    """Seconds (median of REPEATS, levels in turn) and bytes of the pictures at each of `PNG_LEVELS`."""
    images = pictures(maps)
    rows = {level: {"seconds": []} for level in PNG_LEVELS}
    for _ in range(REPEATS):
        for level in PNG_LEVELS:
            start = time.perf_counter()
            for name, image in images.items():
                Image.fromarray(image).save(scratch / f"{name}_{level}.png", format="PNG", compress_level=level)
            rows[level]["seconds"].append(time.perf_counter() - start)
    for level in PNG_LEVELS:
        rows[level]["bytes"] = sum(os.path.getsize(scratch / f"{name}_{level}.png") for name in images)
        rows[level]["median_s"] = float(np.median(rows[level]["seconds"]))
    return rows


def _read(path: Path, ndim: int) -> np.ndarray:
    image = read_image(path)
    return image[..., 0] if ndim == 2 else image  # a Y image is read as grey RGB


def main() -> int:
    maps = fit_like_maps()
    control_before = control_seconds()
    rows = {name: {"seconds": []} for name in COMPRESSIONS}
    with tempfile.TemporaryDirectory(prefix="bench_exr.") as scratch:
        for name in COMPRESSIONS:
            (Path(scratch) / name).mkdir()
        for _ in range(REPEATS):  # the compressions in turn, so that the machine's drift falls on all alike
            for name in COMPRESSIONS:
                start = time.perf_counter()
                write_all(maps, Path(scratch) / name, getattr(OpenEXR, f"{name}_COMPRESSION"))
                rows[name]["seconds"].append(time.perf_counter() - start)
        for name in COMPRESSIONS:
            folder = Path(scratch) / name
            rows[name]["bytes"] = sum(os.path.getsize(folder / f"{map_name}.exr") for map_name in maps)
            rows[name]["lossless"] = all(np.array_equal(_read(folder / f"{map_name}.exr", image.ndim), image)
                                         for map_name, image in maps.items())
            rows[name]["median_s"] = float(np.median(rows[name]["seconds"]))
        png = png_levels(maps, Path(scratch))
    smallest_png = min(PNG_LEVELS, key=lambda level: png[level]["bytes"])
    chosen_png = min((level for level in PNG_LEVELS if png[level]["bytes"] <= 1.2 * png[smallest_png]["bytes"]),
                     key=lambda level: png[level]["median_s"])
    smallest = min(COMPRESSIONS, key=lambda name: rows[name]["bytes"])
    fastest_small = min((name for name in COMPRESSIONS if rows[name]["bytes"] <= 1.05 * rows[smallest]["bytes"]),
                        key=lambda name: rows[name]["median_s"])
    result = {"benchmark": f"EXR compression of a fit folder's eight maps at T = {TEXTURE_RES}, lossless kinds",
              **machine(), "control_s_before": control_before, "control_s_after": control_seconds(),
              "repeats": REPEATS, "compressions": rows, "smallest": smallest,
              "fastest_within_5_percent_of_smallest": fastest_small,
              "png_levels": {str(level): row for level, row in png.items()},
              "png_fastest_within_20_percent_of_smallest": chosen_png,
              "measured": time.strftime("%Y-%m-%d %H:%M")}
    save_results("bench_exr", result)
    for name in COMPRESSIONS:
        print(f"{name:5s} {rows[name]['median_s']:.3f} s  {rows[name]['bytes'] / 2 ** 20:6.2f} MiB  "
              f"lossless {rows[name]['lossless']}")
    for level in PNG_LEVELS:
        print(f"PNG level {level} {png[level]['median_s']:.3f} s  {png[level]['bytes'] / 2 ** 20:6.2f} MiB")
    print(f"PNG: level {chosen_png} (the fastest within 20 % of the smallest)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
