"""The output stage: what a fit leaves behind, and how it is judged (docs/method.md#outputs, docs/method.md#evaluation).

Modules
-------
export
    Hole-free textures, EXR/PNG maps and ``summary.json`` of a fit folder.
gltf
    The glTF 2.0 binary of a mesh with its PBR material.
fit_folder
    A fit folder read back (`FitOutputs`, `load_fit`).
metrics
    Stanford-ORB's relighting scores (PSNR-H, PSNR-L, SSIM, LPIPS) and texture-space scores.
relight
    Relighting an estimate under a capture's test views with Mitsuba, and scoring it (its
    `freqbrdf.outputs.relight.evaluate` is not re-exported: the name is the ``evaluate`` module's).
sparsification
    Spearman correlation and sparsification curves (AUSE, AURG) of an uncertainty; not
    re-exported here, because it imports ``scipy.stats``, which a fit never needs.
evaluate
    `evaluate_fit`: all of the above for a fit folder, written to ``<fit>/evaluation``.
report
    `write_report`: a self-contained ``report.html`` of a fit folder.
"""

from freqbrdf.outputs.evaluate import evaluate_fit
from freqbrdf.outputs.export import (
    ROUGHNESS_STD_DESCRIPTION,
    coverage,
    entropy_description,
    entropy_texture,
    flags_picture,
    material_textures,
    roughness_std_texture,
    roughness_std_values,
    to_float16,
    write_fit_outputs,
    write_material_previews,
    write_scalar_map,
)
from freqbrdf.outputs.fit_folder import FitOutputs, check_output_folder, load_fit
from freqbrdf.outputs.gltf import gltf_bytes, write_gltf
from freqbrdf.outputs.metrics import (
    PSNRResult,
    erode_mask,
    lpips_unavailable,
    lpips_vgg,
    mean_scores,
    orb_psnr,
    relighting_scores,
    ssim,
    texture_scores,
)
from freqbrdf.outputs.relight import (
    Evaluation,
    RelightSettings,
    RelitView,
    comparison_image,
    relight_views,
    texture_metrics,
    write_evaluation,
)
from freqbrdf.outputs.report import write_report

__all__ = [
    "Evaluation",
    "FitOutputs",
    "PSNRResult",
    "ROUGHNESS_STD_DESCRIPTION",
    "RelightSettings",
    "RelitView",
    "check_output_folder",
    "comparison_image",
    "coverage",
    "entropy_description",
    "entropy_texture",
    "erode_mask",
    "evaluate_fit",
    "flags_picture",
    "gltf_bytes",
    "load_fit",
    "lpips_unavailable",
    "lpips_vgg",
    "material_textures",
    "mean_scores",
    "orb_psnr",
    "relight_views",
    "relighting_scores",
    "roughness_std_texture",
    "roughness_std_values",
    "ssim",
    "texture_metrics",
    "texture_scores",
    "to_float16",
    "write_evaluation",
    "write_fit_outputs",
    "write_gltf",
    "write_material_previews",
    "write_report",
    "write_scalar_map",
]
