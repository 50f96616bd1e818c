"""Applications of the uncertainty: guidance and inpainting (docs/method.md#applications).

Each reads a fit's observations, estimate and uncertainty and gives something a user acts on:
where to photograph next, and material maps whose uncertain regions are filled. Sharing across
the surface is part of the estimate itself (`freqbrdf.estimate.surface`).

Modules
-------
guidance
    Capture guidance: the next views by the expected drop of the whole-surface posterior's
    uncertainty (`select_views`), its model (`UncertaintyModel`) and incremental state
    (`GuidanceState`, `add_view`).
information
    What a candidate view would tell the estimate before it is taken: Fisher information on
    roughness (`roughness_information`) and metal evidence (`view_information`).
candidates
    Candidate views for guidance (`sample_candidates`, `load_candidates`,
    `farthest_point_views`) and what each would sample (`view_samples`, `candidate_samples`).
next_views
    The ``next_views`` folder: the ranked cameras, a picture of them and a summary
    (`write_next_views`).
inpaint
    Inpainting a fit's maps where the fit cannot vouch for them, chart by chart, with a
    biharmonic or a diffusion backend.
"""

from freqbrdf.applications.candidates import (
    CandidateSamples,
    candidate_samples,
    farthest_point_views,
    load_candidates,
    sample_candidates,
    view_directions,
    view_samples,
)
from freqbrdf.applications.guidance import (
    MAX_TEXELS,
    GuidanceState,
    Pick,
    SurfaceFit,
    UncertaintyModel,
    add_view,
    expected_uncertainty,
    initial_state,
    select_views,
    state_with_views,
    surface_fit,
    texel_std,
    texel_uncertainty,
    uncertainty_model,
    view_gain,
)
from freqbrdf.applications.information import (
    FISHER_ENTRIES,
    LIGHT_LMAX,
    ViewInformation,
    roughness_information,
    view_information,
)
from freqbrdf.applications.inpaint import (
    MAP_NAMES,
    MASK_PNG,
    Fill,
    Inpainted,
    InpaintSettings,
    biharmonic_fill,
    chart_labels,
    diffusion_fill,
    inpaint_maps,
    inpaint_mask,
    load_diffusion_fill,
)
from freqbrdf.applications.next_views import (
    NEXT_VIEWS_FILE,
    PICTURE_FILE,
    SUMMARY_FILE,
    plot_views,
    write_next_views,
)

__all__ = [
    "FISHER_ENTRIES",
    "LIGHT_LMAX",
    "MAP_NAMES",
    "MASK_PNG",
    "MAX_TEXELS",
    "NEXT_VIEWS_FILE",
    "PICTURE_FILE",
    "SUMMARY_FILE",
    "CandidateSamples",
    "Fill",
    "GuidanceState",
    "InpaintSettings",
    "Inpainted",
    "Pick",
    "SurfaceFit",
    "UncertaintyModel",
    "ViewInformation",
    "add_view",
    "biharmonic_fill",
    "candidate_samples",
    "chart_labels",
    "diffusion_fill",
    "expected_uncertainty",
    "farthest_point_views",
    "initial_state",
    "inpaint_maps",
    "inpaint_mask",
    "load_candidates",
    "load_diffusion_fill",
    "plot_views",
    "roughness_information",
    "sample_candidates",
    "select_views",
    "state_with_views",
    "surface_fit",
    "texel_std",
    "texel_uncertainty",
    "uncertainty_model",
    "view_directions",
    "view_gain",
    "view_information",
    "view_samples",
    "write_next_views",
]
