"""The glTF 2.0 binary (GLB) of a mesh with its PBR metallic-roughness material (docs/method.md#outputs).

The encoder follows the glTF 2.0 spec's conventions (section 3.9 "Materials"):

- ``baseColorTexture``: sRGB-encoded 8-bit PNG of the linear base colour;
- ``metallicRoughnessTexture``: linear 8-bit PNG, roughness in G, metallic in B, R = 255. The spec
  says R must be ignored; 255 is chosen because tools that pack occlusion into R (ORM textures)
  then read "not occluded";
- ``metallicFactor = roughnessFactor = 1`` (the textures carry the values);
- UV origin at the image's top-left: our OBJ-style v (up) is flipped to 1 - v, and texture row 0,
  which is v = 1 in our convention, lands at v_glTF = 0;
- vertex normals are included; samplers are bilinear with mip-maps and clamp to edge, as the
  Mitsuba textures of `freqbrdf.render.scenes.principled_bsdf`;
- every vertex-attribute and index bufferView has its target, ``asset.generator`` is
  "freqbrdf <version>", and the images, textures and material are named (docs/formats.md).
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

from freqbrdf import __version__
from freqbrdf.capture.mesh import Mesh
from freqbrdf.fileio import atomic_path
from freqbrdf.images import linear_to_srgb
from freqbrdf.model.materials import MaterialMaps

__all__ = ["gltf_bytes", "write_gltf"]

METALLIC_ROUGHNESS_R = 255  # unused channel of the glTF metallic-roughness texture (see above)
# Files of a fit folder written at once (see write_fit_outputs); more threads than jobs idle.
WRITER_THREADS = 4
# glTF enums (OpenGL): sampler LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE; bufferView targets
# ARRAY_BUFFER (vertex attributes), ELEMENT_ARRAY_BUFFER (indices); accessor component types;
# primitive mode TRIANGLES.
GL_LINEAR, GL_LINEAR_MIPMAP_LINEAR, GL_CLAMP_TO_EDGE = 9729, 9987, 33071
GL_ARRAY_BUFFER, GL_ELEMENT_ARRAY_BUFFER = 34962, 34963
GL_FLOAT, GL_UNSIGNED_INT = 5126, 5125
GL_TRIANGLES = 4


def write_gltf(path: str | Path, mesh: Mesh, maps: MaterialMaps) -> None:
    """Write a glTF 2.0 binary of a mesh with its PBR metallic-roughness material, atomically.

    Conventions: see the module docstring. The file passes the Khronos glTF validator without a
    message and holds no timestamp: the same mesh and maps give the same bytes.

    Parameters
    ----------
    path : str or Path
        The ``.glb`` file.
    mesh : Mesh
        The mesh: vertices (V, 3), normals (V, 3), uv (V, 2), faces (F, 3); its vertices are kept
        as they are (no merging across UV seams).
    maps : MaterialMaps
        Base colour (T, T, 3), roughness and metallic (T, T) in [0, 1].
    """
    data = gltf_bytes(mesh, maps)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def gltf_bytes(mesh: Mesh, maps: MaterialMaps) -> bytes:
    """Encode a mesh with its PBR metallic-roughness material as a glTF 2.0 binary (GLB).

    One buffer holds, in order, the positions, normals and texture coordinates (one bufferView
    each, target ARRAY_BUFFER), the indices (target ELEMENT_ARRAY_BUFFER) and the two PNG
    textures (no target, as images take none); each bufferView starts on a 4-byte boundary.

    Parameters
    ----------
    mesh : Mesh
        The mesh: vertices (V, 3), normals (V, 3), uv (V, 2), faces (F, 3).
    maps : MaterialMaps
        Base colour (T, T, 3), roughness and metallic (T, T) in [0, 1].

    Returns
    -------
    bytes
        The GLB file's content.
    """
    base_color = _to_uint8(linear_to_srgb(maps.base_color))  # (T, T, 3)
    metallic_roughness = np.stack(
        [
            np.full(maps.roughness.shape, METALLIC_ROUGHNESS_R, np.uint8),
            _to_uint8(maps.roughness),
            _to_uint8(maps.metallic),
        ],
        axis=-1,
    )
    positions = np.ascontiguousarray(mesh.vertices, np.float32)
    normals = np.asarray(mesh.normals, np.float64)
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.ascontiguousarray(np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0),
                                   np.float32)
    uv = np.asarray(mesh.uv, np.float64)
    texcoords = np.ascontiguousarray(np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1), np.float32)  # v flips
    indices = np.ascontiguousarray(mesh.faces, np.uint32).reshape(-1)

    chunks: list[bytes] = []
    views: list[dict] = []

    def add_view(data: bytes, name: str, target: int | None) -> int:
        offset = sum(len(chunk) for chunk in chunks)
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data), "name": name}
        if target is not None:
            view["target"] = target
        views.append(view)
        chunks.append(data + b"\0" * (-len(data) % 4))
        return len(views) - 1

    accessors = []
    for name, values, kind in (("POSITION", positions, "VEC3"), ("NORMAL", normals, "VEC3"),
                               ("TEXCOORD_0", texcoords, "VEC2")):
        accessor = {"bufferView": add_view(values.tobytes(), name, GL_ARRAY_BUFFER),
                    "componentType": GL_FLOAT, "count": len(values), "type": kind}
        if name == "POSITION":  # required on positions; float32 values are exact in JSON doubles
            accessor["min"] = [float(value) for value in positions.min(axis=0)]
            accessor["max"] = [float(value) for value in positions.max(axis=0)]
        accessors.append(accessor)
    accessors.append({"bufferView": add_view(indices.tobytes(), "indices", GL_ELEMENT_ARRAY_BUFFER),
                      "componentType": GL_UNSIGNED_INT, "count": len(indices), "type": "SCALAR"})
    images = [
        {"name": name, "mimeType": "image/png", "bufferView": add_view(_png_bytes(pixels), name, None)}
        for name, pixels in (("base_color", base_color), ("metallic_roughness", metallic_roughness))
    ]
    document = {
        "asset": {"version": "2.0", "generator": f"freqbrdf {__version__}"},
        "scene": 0,
        "scenes": [{"name": "freqbrdf", "nodes": [0]}],
        "nodes": [{"name": "mesh", "mesh": 0}],
        "meshes": [{"name": "mesh", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
            "indices": 3, "material": 0, "mode": GL_TRIANGLES,
        }]}],
        "materials": [{
            "name": "freqbrdf",
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": 0},
                "metallicRoughnessTexture": {"index": 1},
                "metallicFactor": 1.0,
                "roughnessFactor": 1.0,
            },
        }],
        "textures": [{"name": image["name"], "sampler": 0, "source": index} for index, image in enumerate(images)],
        "images": images,
        "samplers": [{"magFilter": GL_LINEAR, "minFilter": GL_LINEAR_MIPMAP_LINEAR,
                      "wrapS": GL_CLAMP_TO_EDGE, "wrapT": GL_CLAMP_TO_EDGE}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": sum(len(chunk) for chunk in chunks)}],
    }
    content = json.dumps(document, separators=(",", ":")).encode("utf-8")
    content += b" " * (-len(content) % 4)  # the JSON chunk is padded with spaces, the binary one with zeros
    binary = b"".join(chunks)
    length = 12 + 8 + len(content) + 8 + len(binary)
    return b"".join([
        struct.pack("<4sII", b"glTF", 2, length),
        struct.pack("<I4s", len(content), b"JSON"), content,
        struct.pack("<I4s", len(binary), b"BIN\0"), binary,
    ])


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.round(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)


def _png_bytes(pixels: np.ndarray) -> bytes:
    """Encode (T, T, 3) uint8 as PNG bytes (PIL's PNG writer embeds no time)."""
    buffer = io.BytesIO()
    Image.fromarray(pixels, "RGB").save(buffer, format="PNG")
    return buffer.getvalue()
