"""Stanford-ORB relighting metrics and texture metrics, checked against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from freqbrdf.model.materials import MaterialMaps
from freqbrdf.outputs import metrics


def srgb(linear: float) -> float:
    """The sRGB encoding written out here, independently of freqbrdf.images."""
    return 12.92 * linear if linear <= 0.0031308 else 1.055 * linear ** (1 / 2.4) - 0.055


def grey(values: np.ndarray) -> np.ndarray:
    """(H, W) -> (H, W, 3) with equal channels."""
    return np.repeat(np.asarray(values, np.float64)[..., None], 3, axis=-1)


def test_erode_mask_shrinks_by_two_pixels_but_not_at_the_image_border():
    mask = np.zeros((15, 15), bool)
    mask[3:12, 3:12] = True  # 9 x 9 block
    eroded = metrics.erode_mask(mask)
    expected = np.zeros_like(mask)
    expected[5:10, 5:10] = True
    assert np.array_equal(eroded, expected)
    # As OpenCV's erode: outside the image counts as inside the mask.
    assert metrics.erode_mask(np.ones((6, 6), bool)).all()


def test_psnr_hdr_by_hand_normalisation_scale_and_mse_over_all_pixels():
    # 4 x 4 image, mask = left half. Inside: columns of 0.2 and 0.4; prediction 1 everywhere.
    gt = grey(np.tile([0.2, 0.4, 3.0, 7.0], (4, 1)))  # right half: background, must not count
    pred = grey(np.ones((4, 4)))
    mask = np.zeros((4, 4), bool)
    mask[:, :2] = True
    result = metrics.orb_psnr(pred, gt, mask, max_value=4.0, srgb_normalise=True, tonemap=False)

    # scale = sum(gt pred) / sum(pred^2) over the mask = mean(0.2, 0.4) = 0.3 per channel.
    np.testing.assert_allclose(result.scale, [0.3, 0.3, 0.3])
    # Normalisation factor: mean over ALL pixels of srgb(clip(gt)) over that of clip(gt);
    # background is zero in both, so it is the ratio over the masked values.
    factor = (srgb(0.2) + srgb(0.4)) / (0.2 + 0.4)
    # Errors +-0.1 (times the factor) in 8 of 16 pixels; MSE is over all 16 pixels.
    mse = 8 * (0.1 * factor) ** 2 / 16
    floor_mse = (4 * (0.5 - 0.2 * factor) ** 2 + 4 * (0.5 - 0.4 * factor) ** 2) / 16
    assert -10 * math.log10(mse) > -10 * math.log10(floor_mse)  # not floored
    # float32 sRGB encoding: agreement to ~1e-6 dB
    assert result.psnr == pytest.approx(-10 * math.log10(mse), abs=1e-5)
    assert result.floor == pytest.approx(-10 * math.log10(floor_mse), abs=1e-5)
    assert np.all(result.reference[:, 2:] == 0) and np.all(result.prediction[:, 2:] == 0)


def test_psnr_ldr_by_hand_clips_then_encodes():
    # Unscaled: reference 0.8 and 2.5 (clipped to 1), prediction 0.6 and 0.9.
    gt = grey([[0.8, 2.5]])
    pred = grey([[0.6, 0.9]])
    mask = np.ones((1, 2), bool)
    result = metrics.orb_psnr(pred, gt, mask, 1.0, srgb_normalise=False, tonemap=True, scale_invariant=False)
    mse = ((srgb(0.6) - srgb(0.8)) ** 2 + (srgb(0.9) - srgb(1.0)) ** 2) / 2
    assert result.psnr == pytest.approx(-10 * math.log10(mse), abs=1e-5)


def test_psnr_is_floored_at_the_score_of_a_constant_half():
    gt = grey(np.full((3, 3), 0.9))
    pred = np.zeros_like(gt)  # a dark channel's scale (ORB: the reference mean) cannot help it
    result = metrics.orb_psnr(pred, gt, np.ones((3, 3), bool), 1.0, srgb_normalise=False, tonemap=True)
    floor = -10 * math.log10((0.5 - srgb(0.9)) ** 2)
    assert -10 * math.log10(srgb(0.9) ** 2) < floor  # the black image alone would score lower
    assert result.psnr == pytest.approx(floor, abs=1e-5)
    assert result.floor == pytest.approx(floor, abs=1e-5)


def random_pair(seed: int = 0, size: int = 24):
    rng = np.random.default_rng(seed)
    reference = rng.uniform(0.0, 3.0, (size, size, 3)) * rng.uniform(0.2, 1.0, (size, size, 1))
    prediction = reference * rng.uniform(0.7, 1.3, reference.shape)
    mask = np.zeros((size, size), bool)
    mask[3:-3, 4:-2] = True
    return prediction, reference, mask


def test_perfect_prediction_up_to_per_channel_scale_scores_infinity_and_ssim_one():
    _, reference, mask = random_pair()
    # Powers of two keep the scaled prediction exactly equal to the reference after rescaling.
    for prediction in (reference, reference * np.array([2.0, 0.5, 4.0])):
        scores = metrics.relighting_scores(prediction, reference, mask, with_lpips=False)
        assert scores["psnr_hdr"] == math.inf and scores["psnr_ldr"] == math.inf
        # Not exactly 1: kornia's eps = 1e-12 in the denominator costs 1e-12 / (C1 C2) ~ 1e-5 on
        # the black background (mean 0, variance 0), as in ORB's numbers.
        assert scores["ssim"] == pytest.approx(1.0, abs=2e-5)
    np.testing.assert_allclose(scores["scale"], [0.5, 2.0, 0.25])


def test_scores_are_invariant_to_a_per_channel_scale_of_the_prediction():
    prediction, reference, mask = random_pair(1)
    plain = metrics.relighting_scores(prediction, reference, mask, with_lpips=False)
    scaled = metrics.relighting_scores(prediction * np.array([4.0, 0.3, 1.7]), reference, mask, with_lpips=False)
    assert math.isfinite(plain["psnr_hdr"]) and math.isfinite(plain["psnr_ldr"])
    for key in ("psnr_hdr", "psnr_ldr", "ssim"):
        assert scaled[key] == pytest.approx(plain[key], abs=1e-9)
    # A worse prediction scores lower on every measure.
    worse = metrics.relighting_scores(prediction ** 1.5, reference, mask, with_lpips=False)
    assert worse["psnr_hdr"] < plain["psnr_hdr"] and worse["psnr_ldr"] < plain["psnr_ldr"]
    assert worse["ssim"] < plain["ssim"]


def test_ssim_of_constant_images_by_hand():
    a, b = 0.2, 0.6
    value = metrics.ssim(np.full((5, 5, 3), a), np.full((5, 5, 3), b))
    c1, c2, eps = 0.01**2, 0.03**2, 1e-12  # variances vanish: SSIM is the luminance term
    assert value == pytest.approx((2 * a * b + c1) * c2 / ((a * a + b * b + c1) * c2 + eps), rel=1e-9)


def test_ssim_matches_a_direct_windowed_computation():
    """kornia's SSIM written pixel by pixel: 3x3 Gaussian (sigma 1.5), reflect padding."""
    rng = np.random.default_rng(2)
    x, y = rng.random((5, 6, 3)), rng.random((5, 6, 3))
    g = np.exp(-np.array([1.0, 0.0, 1.0]) / (2 * 1.5**2))
    window = np.outer(g, g) / g.sum() ** 2
    px, py = (np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="reflect") for image in (x, y))
    total = 0.0
    for i in range(5):
        for j in range(6):
            wx, wy = px[i : i + 3, j : j + 3], py[i : i + 3, j : j + 3]  # (3, 3, 3)
            w = window[..., None]
            mx, my = (w * wx).sum((0, 1)), (w * wy).sum((0, 1))
            vx = (w * wx * wx).sum((0, 1)) - mx**2
            vy = (w * wy * wy).sum((0, 1)) - my**2
            cxy = (w * wx * wy).sum((0, 1)) - mx * my
            s = ((2 * mx * my + 1e-4) * (2 * cxy + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
            total += s.sum()
    assert metrics.ssim(x, y) == pytest.approx(total / (5 * 6 * 3), abs=1e-9)


def test_lpips_reports_why_it_was_skipped():
    prediction, reference, mask = random_pair(3)
    scores = metrics.relighting_scores(prediction, reference, mask, with_lpips=False)
    assert scores["lpips"] is None and scores["lpips_skipped"] == "not requested"
    assert metrics.mean_scores([scores])["lpips"] is None


@pytest.mark.skipif(
    metrics.lpips_unavailable() is not None,
    reason=f"LPIPS weights not installed: {metrics.lpips_unavailable()}",
)
def test_lpips_vgg_is_zero_for_equal_images_symmetric_and_grows_with_noise():
    rng = np.random.default_rng(4)
    image = rng.random((32, 32, 3)).astype(np.float32)
    noise = rng.normal(size=image.shape).astype(np.float32)
    assert metrics.lpips_vgg(image, image) == 0.0
    distances = [metrics.lpips_vgg(image, np.clip(image + level * noise, 0, 1)) for level in (0.02, 0.1, 0.4)]
    assert 0.0 < distances[0] < distances[1] < distances[2]
    other = np.clip(image + 0.1 * noise, 0, 1)
    assert metrics.lpips_vgg(other, image) == pytest.approx(metrics.lpips_vgg(image, other), rel=1e-5)
    prediction, reference, mask = random_pair(5, size=32)
    scores = metrics.relighting_scores(prediction, reference, mask)
    assert scores["lpips"] > 0.0 and "lpips_skipped" not in scores


def test_texture_scores_by_hand_with_resampled_truth():
    size = 8
    estimate = MaterialMaps(
        np.full((size, size, 3), 0.5, np.float32),
        np.full((size, size), 0.3, np.float32),
        np.full((size, size), 1.0, np.float32),
    )
    truth = MaterialMaps(  # twice the resolution, constant: resampling keeps the values
        np.full((2 * size, 2 * size, 3), 0.6, np.float32),
        np.full((2 * size, 2 * size), 0.5, np.float32),
        np.full((2 * size, 2 * size), 0.25, np.float32),
    )
    observed = np.zeros((size, size), bool)
    observed[:, :3] = True
    scores = metrics.texture_scores(estimate, truth, observed)
    assert scores["texels"] == 24
    assert scores["base_color_psnr"] == pytest.approx(20.0, abs=1e-5)  # error 0.1 everywhere
    assert scores["roughness_mae"] == pytest.approx(0.2, abs=1e-6)
    assert scores["metallic_mae"] == pytest.approx(0.75, abs=1e-6)
    assert metrics.texture_scores(estimate, estimate, observed)["base_color_psnr"] == math.inf
