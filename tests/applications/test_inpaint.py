"""Inpainting: the mask, chart by chart filling without bleeding, the backends, the command."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from PIL import Image

from freqbrdf import pipeline
from freqbrdf.applications.inpaint import (
    InpaintSettings,
    biharmonic_fill,
    chart_labels,
    diffusion_fill,
    inpaint_maps,
    inpaint_mask,
    load_diffusion_fill,
)
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.images import srgb_to_linear
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.outputs.fit_folder import load_fit
from freqbrdf.pipeline import inpaint_fit
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import (
    FLAG_AMBIGUOUS,
    FLAG_BELOW_BOUND,
    FLAG_FEW_SAMPLES,
    FLAG_UNOBSERVED,
)

RES = 24


def two_charts() -> tuple[MaterialMaps, np.ndarray]:
    """A 24 x 24 texture: chart A (rows 2-11, a roughness ramp) and chart B (rows 13-21, constant),
    one texel of empty atlas space between them, whose maps hold a loud value (as if dilated)."""
    atlas = np.zeros((RES, RES), bool)
    atlas[2:12, 2:22] = True  # A
    atlas[13:22, 2:22] = True  # B
    columns = np.arange(RES, dtype=np.float32)
    roughness = np.where(atlas, 0.0, 1.0).astype(np.float32)
    roughness[2:12] = 0.1 + 0.03 * columns  # A: linear in the column
    roughness[13:22] = 0.9
    roughness[~atlas] = 1.0
    base_color = np.zeros((RES, RES, 3), np.float32)
    base_color[2:12] = (0.8, 0.2, 0.1)
    base_color[13:22] = (0.1, 0.3, 0.9)
    metallic = np.zeros((RES, RES), np.float32)
    metallic[13:22] = 1.0
    return MaterialMaps(base_color, roughness, metallic), atlas


def test_holes_are_filled_from_their_own_chart_only():
    maps, atlas = two_charts()
    labels, n_charts = chart_labels(atlas)
    assert n_charts == 2 and labels[5, 5] != labels[15, 5]
    mask = np.zeros_like(atlas)
    mask[8:12, 8:14] = True  # a hole of A on its edge next to B
    mask[3:6, 15:19] = True
    damaged = MaterialMaps(np.where(mask[..., None], 0.5, maps.base_color).astype(np.float32),
                           np.where(mask, 0.5, maps.roughness).astype(np.float32),
                           np.where(mask, 0.5, maps.metallic).astype(np.float32))
    result = inpaint_maps(damaged, atlas, mask, biharmonic_fill, dilation_px=2)
    # A's roughness is linear in the column: the biharmonic continuation restores it, untouched by
    # B's 0.9 one row away and by the 1.0 in the gap.
    np.testing.assert_allclose(result.maps.roughness[mask], maps.roughness[mask], atol=2e-3)
    np.testing.assert_allclose(result.maps.base_color[mask], np.broadcast_to((0.8, 0.2, 0.1), (mask.sum(), 3)),
                               atol=1e-6)
    np.testing.assert_allclose(result.maps.metallic[mask], 0.0, atol=1e-6)
    confident = atlas & ~mask  # unchanged, bit for bit
    np.testing.assert_array_equal(result.maps.roughness[confident], maps.roughness[confident])
    np.testing.assert_array_equal(result.maps.base_color[confident], maps.base_color[confident])
    # The seam padding is regrown from the atlas: the gap row now blends A and B.
    assert 0.1 < result.maps.roughness[12, 10] < 0.9 and result.unfilled_texels == 0


def test_a_chart_without_confident_texels_is_left_as_it_was():
    maps, atlas = two_charts()
    mask = np.zeros_like(atlas)
    mask[13:22, 2:22] = True  # all of B
    mask[4, 4] = True
    result = inpaint_maps(maps, atlas, mask, biharmonic_fill, names=("roughness",))
    assert result.unfilled_texels == mask[13:22].sum()
    np.testing.assert_array_equal(result.maps.roughness[13:22, 2:22], maps.roughness[13:22, 2:22])
    np.testing.assert_array_equal(result.maps.base_color[atlas], maps.base_color[atlas])  # not asked for
    with pytest.raises(ValueError, match="maps to inpaint"):
        inpaint_maps(maps, atlas, mask, biharmonic_fill, names=("albedo",))


def test_mask_from_flags_or_threshold():
    atlas = np.ones((2, 3), bool)
    atlas[1, 2] = False
    texel_index = np.array([0, 1, 2, 3, 4])
    flags = np.array([FLAG_UNOBSERVED, FLAG_AMBIGUOUS, FLAG_BELOW_BOUND, FLAG_FEW_SAMPLES, 0], np.uint8)
    entropy = np.array([1.0, 0.7, 0.1, 0.35, 0.2], np.float32)
    np.testing.assert_array_equal(inpaint_mask(atlas, texel_index, flags, entropy, None).ravel(),
                                  [True, True, False, False, False, False])
    np.testing.assert_array_equal(inpaint_mask(atlas, texel_index, flags, entropy, 0.3).ravel(),
                                  [True, True, False, True, False, False])


class ConstantPipeline:
    """Stands in for a diffusers inpainting pipeline: paints everything one colour, records its inputs."""

    def __init__(self, colour: tuple[int, int, int]):
        self.colour = colour
        self.calls: list[dict] = []

    def __call__(self, **arguments):
        self.calls.append(arguments)
        size = (arguments["width"], arguments["height"])
        return SimpleNamespace(images=[Image.new("RGB", size, self.colour)])


def test_diffusion_wiring_sends_each_chart_and_map_and_keeps_only_the_holes():
    maps, atlas = two_charts()
    mask = np.zeros_like(atlas)
    mask[4:7, 4:9] = True  # in A
    mask[15:17, 10:12] = True  # in B
    painter = ConstantPipeline((255, 128, 0))
    settings = InpaintSettings(backend="diffusion", steps=3, size=32, prompt="stone")
    result = inpaint_maps(maps, atlas, mask, diffusion_fill(painter, settings), dilation_px=0)
    assert len(painter.calls) == 2 * 3  # two charts, three maps each
    call = painter.calls[0]
    assert (call["prompt"], call["num_inference_steps"], call["height"]) == ("stone", 3, 32)
    assert call["mask_image"].size == (32, 32) and call["image"].mode == "RGB"
    # Chart A's box is 10 x 20 texels: the mask sent is white exactly over the hole, resized.
    sent = np.asarray(call["mask_image"].resize((20, 10), Image.NEAREST)) > 127
    np.testing.assert_array_equal(sent, mask[2:12, 2:22])
    # Base colour comes back from sRGB, scalar maps from grey (the mean of R, G, B).
    expected_colour = srgb_to_linear(np.array([1.0, 128 / 255, 0.0]))
    np.testing.assert_allclose(result.maps.base_color[mask], np.broadcast_to(expected_colour, (mask.sum(), 3)),
                               atol=1e-6)
    np.testing.assert_allclose(result.maps.roughness[mask], (1.0 + 128 / 255) / 3, atol=1e-6)
    np.testing.assert_array_equal(result.maps.metallic[atlas & ~mask], maps.metallic[atlas & ~mask])


def _tiny_diffusers_pipeline(folder):
    """A randomly initialised Stable Diffusion inpainting pipeline, small enough for a CPU test."""
    torch = pytest.importorskip("torch", reason="the diffusion backend needs torch (extra [diffusion])")
    diffusers = pytest.importorskip("diffusers", reason="the diffusion backend needs diffusers (extra [diffusion])")
    transformers = pytest.importorskip("transformers", reason="the diffusion backend needs transformers")
    torch.manual_seed(0)
    unet = diffusers.UNet2DConditionModel(
        block_out_channels=(32, 64), layers_per_block=1, sample_size=16, in_channels=9, out_channels=4,
        down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"), up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"),
        cross_attention_dim=32,
    )
    vae = diffusers.AutoencoderKL(
        block_out_channels=[32, 64], in_channels=3, out_channels=3, latent_channels=4,
        down_block_types=["DownEncoderBlock2D", "DownEncoderBlock2D"],
        up_block_types=["UpDecoderBlock2D", "UpDecoderBlock2D"],
    )
    text_encoder = transformers.CLIPTextModel(transformers.CLIPTextConfig(
        bos_token_id=0, eos_token_id=1, pad_token_id=1, hidden_size=32, intermediate_size=37,
        num_attention_heads=4, num_hidden_layers=2, vocab_size=100,
    ))
    vocabulary = folder / "vocab"
    vocabulary.mkdir()
    (vocabulary / "vocab.json").write_text(json.dumps({"<|startoftext|>": 0, "<|endoftext|>": 1}))
    (vocabulary / "merges.txt").write_text("#version: 0.2\n")
    tokenizer = transformers.CLIPTokenizer(str(vocabulary / "vocab.json"), str(vocabulary / "merges.txt"),
                                           model_max_length=77)
    built = diffusers.StableDiffusionInpaintPipeline(
        vae=vae, text_encoder=text_encoder, tokenizer=tokenizer, unet=unet,
        scheduler=diffusers.PNDMScheduler(skip_prk_steps=True), safety_checker=None, feature_extractor=None,
        requires_safety_checker=False,
    )
    built.save_pretrained(folder / "model")
    return folder / "model"


def test_diffusion_backend_runs_a_local_pipeline(tmp_path):
    model = _tiny_diffusers_pipeline(tmp_path)
    maps, atlas = two_charts()
    mask = np.zeros_like(atlas)
    mask[4:7, 4:9] = True
    fill = load_diffusion_fill(InpaintSettings(backend="diffusion", model=str(model), steps=2, size=32))
    result = inpaint_maps(maps, atlas, mask, fill)
    assert np.all(np.isfinite(result.maps.base_color))
    assert np.all((result.maps.roughness >= 0) & (result.maps.roughness <= 1))
    np.testing.assert_array_equal(result.maps.roughness[atlas & ~mask], maps.roughness[atlas & ~mask])
    with pytest.raises(InputError, match="model_index.json"):
        load_diffusion_fill(InpaintSettings(backend="diffusion", model=str(tmp_path)))


# --- the command on a real fit ------------------------------------------------------------------

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=1, test_envmaps=1)


@pytest.fixture(scope="module")
def tiny_fit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inpaint")
    capture = synthesize(folder / "capture", TINY, progress=False)
    config = Config(texels=TexelConfig(texture_res=32))
    return pipeline.write_fit(folder / "fit", pipeline.fit(load(capture), config), config)


@pytest.mark.slow
def test_inpaint_command_writes_a_complete_folder(tiny_fit, tmp_path, run_cli, monkeypatch, capsys):
    out = tmp_path / "inpainted"
    assert run_cli("inpaint", tiny_fit, "--out", out, "--threshold", "0.2") == 0
    names = {path.name for path in out.iterdir()}
    assert {"base_color.exr", "roughness.exr", "metallic.exr", "base_color.png", "mask.png", "material.glb",
            "summary.json"} <= names
    summary = json.loads((out / "summary.json").read_text())
    fit = load_fit(tiny_fit)
    atlas = np.zeros(32 * 32, bool)
    atlas[fit.texel_index] = True
    atlas = atlas.reshape(32, 32)
    expected_mask = inpaint_mask(atlas, fit.texel_index, fit.arrays["flags"], fit.arrays["entropy"], 0.2)
    assert summary["masked_texels"] == int(expected_mask.sum()) > 0
    filled = load_material_maps(out)
    keep = atlas & ~expected_mask
    np.testing.assert_array_equal(filled.roughness[keep], fit.maps.roughness[keep])
    assert len(trimesh.load(out / "material.glb").geometry) == 1
    assert "filled" in capsys.readouterr().out


@pytest.mark.slow
def test_inpaint_command_rejects_bad_input(tiny_fit, tmp_path, run_cli, monkeypatch, capsys):
    assert run_cli("inpaint", tmp_path / "missing", "--out", tmp_path / "o") == 2
    assert "fit folder does not exist" in capsys.readouterr().err
    assert run_cli("inpaint", tiny_fit, "--out", tmp_path / "o", "--maps", "albedo") == 2
    assert run_cli("inpaint", tiny_fit, "--out", tmp_path / "o", "--threshold", "1.5") == 2
    assert not (tmp_path / "o").exists()
    with pytest.raises(InputError, match="threshold"):
        inpaint_fit(tiny_fit, tmp_path / "o", InpaintSettings(threshold=-0.1))
    # --model: without the optional extra, or with a folder that is no pipeline, one clear line.
    assert run_cli("inpaint", tiny_fit, "--out", tmp_path / "o", "--model", tmp_path) == 2
    assert "error:" in capsys.readouterr().err
