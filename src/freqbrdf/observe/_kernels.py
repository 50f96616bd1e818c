"""The numba kernels of the observation stage (docs/method.md#observations and docs/method.md#sh-fit).

Private to `freqbrdf.observe.observations`, whose `observe` calls them batch by batch of views:

- `_project_kernel`: each texel's pixel in each view of a batch, its cos(theta_o) and whether it
  faces the camera inside the image (docs/method.md#observations);
- `_shadow_rays` and `_clear_occluded`: the visibility test's segments from the offset texels to
  the camera centres, packed texel by texel, and the samples their hits remove (docs/method.md#observations);
- `_record_kernel`: the observed radiance (bilinear image samples inside the mask), the view
  direction in the texel's frame, the weight and the visibility of each sample, and which of its
  channels a clipped pixel censors;
- `_mirror_directions` and `_unpack_samples`: the world mirror directions r = 2 (n.v) n - v of
  the samples and the band-limited environment looked up there, written beside the radiance
  (docs/method.md#conventions, docs/method.md#band-limit);
- `_sample_offsets` (numpy): where each texel's selected samples start when packed;
- `_weighted_view_sums`: per texel, the weighted sum of a value over its samples (`mean_over_views`);
- `_initialise_signals`: the fitted signals' buffer, with the constant channel at 1 (docs/method.md#forward-model);
- `_sample_bilinear`, `_bilinear_stencil` and `_blend`: bilinear image samples;
- `_lobe_rays`, `_cosine_rays`, `_texels_at_hits` and `_lobe_totals`: the rays `freqbrdf.observe.occlusion`
  traces (each sample's mirror lobe, each texel's cosine rays), the observed texel holding a hit point
  in UV and what each lobe's hits add up to.

Compiled on first use and cached on disk (``cache=True``), so they stay at module level.
"""

import math

import numba
import numpy as np

# A sample must lie fully inside the mask: its four bilinear neighbours all on the object, so
# that silhouette pixels blending object and background are not taken for the object.
MASK_INSIDE = 1.0 - 1e-6


@numba.njit(parallel=True, cache=True)
def _shadow_rays(ray_origin, centres, seen, offsets):
    """Segments from texels to camera centres, as `Occluder.hits_rows` takes them.

    ray_origin (N, 3) float32; centres (B, 3); one ray per True of seen (N, B), packed at
    `_sample_offsets`. Returns origins (3, M), unit directions (3, M) float32 and lengths (M,)
    float32 that stop just short of the camera (cameras never sit on the surface).
    """
    n_rays = offsets[-1]
    origins = np.empty((3, n_rays), dtype=np.float32)
    directions = np.empty((3, n_rays), dtype=np.float32)
    lengths = np.empty(n_rays, dtype=np.float32)
    for t in numba.prange(seen.shape[0]):
        k = offsets[t]
        for b in range(seen.shape[1]):
            if not seen[t, b]:
                continue
            dx = centres[b, 0] - ray_origin[t, 0]
            dy = centres[b, 1] - ray_origin[t, 1]
            dz = centres[b, 2] - ray_origin[t, 2]
            distance = math.sqrt(dx * dx + dy * dy + dz * dz)
            for axis in range(3):
                origins[axis, k] = ray_origin[t, axis]
            directions[0, k], directions[1, k], directions[2, k] = dx / distance, dy / distance, dz / distance
            lengths[k] = distance * (1.0 - 1e-5)
            k += 1
    return origins, directions, lengths


@numba.njit(parallel=True, cache=True)
def _clear_occluded(seen, offsets, hit):
    """Set seen (N, B) to False where the packed ray of that entry (`_sample_offsets`) hit."""
    for t in numba.prange(seen.shape[0]):
        k = offsets[t]
        for b in range(seen.shape[1]):
            if seen[t, b]:
                if hit[k]:
                    seen[t, b] = False
                k += 1


@numba.njit(parallel=True, cache=True)
def _mirror_directions(frame, view_direction, sampled, offsets):
    """Return the (M, 3) world mirror directions r = 2 (n.v) n - v of the selected samples.

    sampled (N, V) bool selects them, packed at offsets (`_sample_offsets`); frame (N, 3, 3)
    rows t, b, n; view_direction (N, V, 3) local. In the local frame the mirror of (x, y, z)
    about n = z is (-x, -y, z).
    """
    mirror = np.empty((offsets[-1], 3))
    for t in numba.prange(sampled.shape[0]):
        k = offsets[t]
        for v in range(sampled.shape[1]):
            if not sampled[t, v]:
                continue
            x, y, z = -np.float64(view_direction[t, v, 0]), -np.float64(view_direction[t, v, 1]), np.float64(
                view_direction[t, v, 2])
            for axis in range(3):
                mirror[k, axis] = x * frame[t, 0, axis] + y * frame[t, 1, axis] + z * frame[t, 2, axis]
            k += 1
    return mirror


@numba.njit(parallel=True, cache=True)
def _initialise_signals(signals, constant):
    """Set signals (N, V, C) to 0 and channel ``constant`` to 1.

    In parallel and in one contiguous pass, which also maps the fresh memory (faster than
    np.zeros and a strided assignment; docs/results.md).
    """
    for t in numba.prange(signals.shape[0]):
        for v in range(signals.shape[1]):
            for k in range(signals.shape[2]):
                signals[t, v, k] = 0.0
            signals[t, v, constant] = 1.0


@numba.njit(parallel=True, cache=True)
def _unpack_samples(sampled, offsets, packed, signals, first_channel):
    """Write the packed row of each selected sample to signals[t, v, first_channel:first_channel + C]."""
    for t in numba.prange(sampled.shape[0]):
        k = offsets[t]
        for v in range(sampled.shape[1]):
            if sampled[t, v]:
                for c in range(packed.shape[1]):
                    signals[t, v, first_channel + c] = packed[k, c]
                k += 1

@numba.njit(parallel=True, cache=True)
def _project_kernel(position, normal, camera_to_world, intrinsics, width, height,
                    pixels, cos_theta, facing, n_facing):
    """Project texels into a batch of B views (OpenGL cameras, see freqbrdf.capture.camera).

    position, normal (N, 3); camera_to_world (B, 4, 4); intrinsics (B, 4) fx, fy, cx, cy; images
    width x height. Writes pixels (N, B, 2) x, y, cos_theta (N, B) between the normal and the
    direction to the camera, and facing (N, B): in front of the camera, inside the image and
    facing it (cos_theta > 0). Pixels are written where facing only. Adds the facing views of
    each texel to n_facing (N,).
    """
    for t in numba.prange(position.shape[0]):
        for b in range(camera_to_world.shape[0]):
            rotation = camera_to_world[b, :3, :3]
            dx = camera_to_world[b, 0, 3] - position[t, 0]
            dy = camera_to_world[b, 1, 3] - position[t, 1]
            dz = camera_to_world[b, 2, 3] - position[t, 2]
            cosine = (normal[t, 0] * dx + normal[t, 1] * dy + normal[t, 2] * dz) / math.sqrt(
                dx * dx + dy * dy + dz * dz
            )
            cos_theta[t, b] = cosine
            # Camera-space coordinates of the texel: R^T (p - c) = -R^T d; depth along -z.
            local_x = -(rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz)
            local_y = -(rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz)
            depth = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
            facing[t, b] = False
            if depth <= 0.0 or cosine <= 0.0:
                continue
            x = intrinsics[b, 2] + intrinsics[b, 0] * local_x / depth
            y = intrinsics[b, 3] - intrinsics[b, 1] * local_y / depth  # camera y up, pixel y down
            if 0.0 <= x <= width and 0.0 <= y <= height:
                pixels[t, b, 0] = x
                pixels[t, b, 1] = y
                facing[t, b] = True
                n_facing[t] += 1


@numba.njit(parallel=True, cache=True)
def _record_kernel(seen, images, masks, ceilings, pixels, cos_theta, position, frame, centres, first_view, signals,
                   view_direction, weight, visible, censored, censored_weight):
    """Record the samples of a batch of B views, texel by texel (contiguous writes).

    seen (N, B): facing and unoccluded; images (B, H, W, 3), masks (B, H, W, 1) in [0, 1], both
    sampled bilinearly; a sample counts where the mask is 1 at all four neighbours. For counted
    samples writes the observed radiance, local view direction, weight and visibility into columns
    first_view + b of the (N, V, ...) outputs. ceilings (B, H, W, 3) is 1 where a channel is
    clipped (or has no rows: none is): a sample whose lookup reads a clipped pixel in a channel is
    censored there (censored (N, V, 3) True) and keeps weight 0, its weight in censored_weight (N, V).
    """
    height, width = images.shape[1], images.shape[2]
    clipping = ceilings.shape[1] > 0
    for t in numba.prange(seen.shape[0]):
        for b in range(seen.shape[1]):
            if not seen[t, b]:
                continue
            row, col, row_next, col_next, fx, fy = _bilinear_stencil(pixels[t, b, 0], pixels[t, b, 1], height, width)
            if _blend(masks[b], row, col, row_next, col_next, fx, fy, 0) < MASK_INSIDE:
                continue
            view = first_view + b
            for c in range(3):
                signals[t, view, c] = _blend(images[b], row, col, row_next, col_next, fx, fy, c)
            dx = centres[b, 0] - position[t, 0]
            dy = centres[b, 1] - position[t, 1]
            dz = centres[b, 2] - position[t, 2]
            inverse_distance = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
            dx *= inverse_distance
            dy *= inverse_distance
            dz *= inverse_distance
            for axis in range(3):
                view_direction[t, view, axis] = frame[t, axis, 0] * dx + frame[t, axis, 1] * dy + frame[t, axis, 2] * dz
            visible[t, view] = True
            any_censored = False
            if clipping:
                for c in range(3):
                    # Any tap on the plateau: the blend of a lower bound and exact values is a lower bound.
                    if (ceilings[b, row, col, c] + ceilings[b, row, col_next, c] + ceilings[b, row_next, col, c]
                            + ceilings[b, row_next, col_next, c]) > 0.0:
                        censored[t, view, c] = True
                        any_censored = True
            if any_censored:
                censored_weight[t, view] = cos_theta[t, b]
            else:
                weight[t, view] = cos_theta[t, b]


@numba.njit(inline="always")
def _bilinear_stencil(x, y, height, width):
    """Return the neighbours and fractions for bilinear interpolation at pixel coordinates (x, y).

    Pixel centres lie at (j + 0.5, i + 0.5); the border is clamped (the edge pixel's value holds
    up to half a pixel beyond its centre).
    """
    x = min(max(x - 0.5, 0.0), width - 1.0)
    y = min(max(y - 0.5, 0.0), height - 1.0)
    col = min(int(x), width - 2) if width > 1 else 0
    row = min(int(y), height - 2) if height > 1 else 0
    return row, col, min(row + 1, height - 1), min(col + 1, width - 1), x - col, y - row


@numba.njit(inline="always")
def _blend(image, row, col, row_next, col_next, fx, fy, c):
    top = image[row, col, c] * (1.0 - fx) + image[row, col_next, c] * fx
    bottom = image[row_next, col, c] * (1.0 - fx) + image[row_next, col_next, c] * fx
    return top * (1.0 - fy) + bottom * fy


@numba.njit(parallel=True, cache=True)
def _sample_bilinear(image, pixels, out):  # image (H, W, C); pixels (M, 2) x, y; out (M, C)
    """Bilinear samples of ``image`` at pixel coordinates (see `_bilinear_stencil`)."""
    height, width, channels = image.shape
    for k in numba.prange(pixels.shape[0]):
        row, col, row_next, col_next, fx, fy = _bilinear_stencil(pixels[k, 0], pixels[k, 1], height, width)
        for c in range(channels):
            out[k, c] = _blend(image, row, col, row_next, col_next, fx, fy, c)


def _sample_offsets(selected: np.ndarray) -> np.ndarray:
    """Return where each texel's selected entries start when they are packed.

    selected (N, B) bool; packed row-major (texel by texel, views in order). Returns (N + 1,)
    int64 offsets, their total at the end.
    """
    offsets = np.zeros(len(selected) + 1, dtype=np.int64)
    np.cumsum(np.count_nonzero(selected, axis=1), out=offsets[1:])
    return offsets


@numba.njit(parallel=True, cache=True)
def _texels_at_hits(face, barycentric, face_xy, texel_of_pixel, observed, ray_origin, points, reach):
    """Find the observed texel holding each hit point in UV, or -1.

    face (M,) and barycentric (M, 2) (weights of the second and third corners) place each hit on
    the mesh; face_xy (F, 3, 2) are the faces' corners in texel coordinates (column, row of texel
    centres); texel_of_pixel (T, T) the row of the texel at each pixel, -1 where none. A texel
    counts where it is observed and its ray origin (N, 3) lies within reach[t] (N,) of the hit's
    world point (M, 3): a pixel on a chart's border can hold a texel of another chart.
    """
    n_hits = face.shape[0]
    res = texel_of_pixel.shape[0]
    texel = np.full(n_hits, -1, dtype=np.int64)
    for k in numba.prange(n_hits):
        f = face[k]
        b1 = barycentric[k, 0]
        b2 = barycentric[k, 1]
        b0 = 1.0 - b1 - b2
        x = b0 * face_xy[f, 0, 0] + b1 * face_xy[f, 1, 0] + b2 * face_xy[f, 2, 0]
        y = b0 * face_xy[f, 0, 1] + b1 * face_xy[f, 1, 1] + b2 * face_xy[f, 2, 1]
        col = min(max(int(math.floor(x + 0.5)), 0), res - 1)
        row = min(max(int(math.floor(y + 0.5)), 0), res - 1)
        t = texel_of_pixel[row, col]
        if t < 0 or not observed[t]:
            continue
        distance_squared = 0.0
        for axis in range(3):
            d = ray_origin[t, axis] - points[k, axis]
            distance_squared += d * d
        if distance_squared <= reach[t] * reach[t]:
            texel[k] = t
    return texel


@numba.njit(parallel=True, cache=True)
def _lobe_rays(ray_origin, texel, mirror, offsets):
    """Build the rays of each sample's mirror lobe, as `Occluder.first_hits_rows` takes them.

    ray_origin (N, 3); texel (S,) the texel of each sample; mirror (S, 3) its unit mirror
    direction (any length: normalised here); offsets (R, 3) the lobe's rays in a frame whose z is
    the mirror direction (x across it, y along it). Ray k is sample k // R's offset k % R. Returns
    origins and unit directions (3, S R) float32.
    """
    n_samples = texel.shape[0]
    n_rays = offsets.shape[0]
    origins = np.empty((3, n_samples * n_rays), dtype=np.float32)
    directions = np.empty((3, n_samples * n_rays), dtype=np.float32)
    for s in numba.prange(n_samples):
        mx, my, mz = mirror[s, 0], mirror[s, 1], mirror[s, 2]
        norm = max(math.sqrt(mx * mx + my * my + mz * mz), 1e-12)
        mx, my, mz = mx / norm, my / norm, mz / norm
        # across = mirror x (x axis, or y where the mirror is close to x), normalised
        if abs(mx) < 0.9:
            ax, ay, az = 0.0, mz, -my
        else:
            ax, ay, az = -mz, 0.0, mx
        length = math.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / length, ay / length, az / length
        bx, by, bz = my * az - mz * ay, mz * ax - mx * az, mx * ay - my * ax  # along = mirror x across
        t = texel[s]
        for r in range(n_rays):
            k = s * n_rays + r
            u, v, w = offsets[r, 0], offsets[r, 1], offsets[r, 2]
            directions[0, k] = u * ax + v * bx + w * mx
            directions[1, k] = u * ay + v * by + w * my
            directions[2, k] = u * az + v * bz + w * mz
            for axis in range(3):
                origins[axis, k] = ray_origin[t, axis]
    return origins, directions


@numba.njit(parallel=True, cache=True)
def _cosine_rays(ray_origin, frame, spin, local, texels):
    """Build each listed texel's cosine rays turned by its spin, as `Occluder.first_hits_rows` takes them.

    ray_origin (N, 3); frame (N, 3, 3) rows tangent, bitangent, normal; spin (N,) radians;
    local (R, 3) directions in a frame with z up; texels (n,). Ray k is texel k // R's ray k % R.
    Returns origins and unit directions (3, n R) float32.
    """
    n_texels = texels.shape[0]
    n_rays = local.shape[0]
    origins = np.empty((3, n_texels * n_rays), dtype=np.float32)
    directions = np.empty((3, n_texels * n_rays), dtype=np.float32)
    for i in numba.prange(n_texels):
        t = texels[i]
        c, s = math.cos(spin[t]), math.sin(spin[t])
        for r in range(n_rays):
            k = i * n_rays + r
            along_tangent = local[r, 0] * c - local[r, 1] * s
            along_bitangent = local[r, 0] * s + local[r, 1] * c
            for axis in range(3):
                directions[axis, k] = (along_tangent * frame[t, 0, axis] + along_bitangent * frame[t, 1, axis]
                                       + local[r, 2] * frame[t, 2, axis])
                origins[axis, k] = ray_origin[t, axis]
    return origins, directions


@numba.njit(cache=True)
def _lobe_totals(hits, weights, shows, n_samples):
    """Sum each sample's lobe rays that hit: their weight and their weighted radiance.

    hits (H,) ascending ray indices, ray k being sample k // R's ray k % R with weight weights[k % R]
    (R,); shows (H, 3) what each hit sees. Returns share (S,) and radiance (S, 3) float64, the sums
    in ray order.
    """
    n_rays = weights.shape[0]
    share = np.zeros(n_samples)
    radiance = np.zeros((n_samples, 3))
    for h in range(hits.shape[0]):
        s = hits[h] // n_rays
        w = weights[hits[h] % n_rays]
        share[s] += w
        for c in range(3):
            radiance[s, c] += w * shows[h, c]
    return share, radiance


@numba.njit(parallel=True, cache=True)
def _weighted_view_sums(weight, values):
    """Per texel: (sum_v w_v, sum_v w_v x_v per channel), in float64.

    weight (N, V), values (N, V, C) of any float type; each texel summed over its views in order.
    Returns total (N,) and sums (N, C).
    """
    n_texels, n_views = weight.shape
    n_channels = values.shape[2]
    total = np.zeros(n_texels)
    sums = np.zeros((n_texels, n_channels))
    for t in numba.prange(n_texels):
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w == 0.0:
                continue
            total[t] += w
            for c in range(n_channels):
                sums[t, c] += w * np.float64(values[t, v, c])
    return total, sums

