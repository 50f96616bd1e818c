"""What a texel reflects under a light: the reflection model of docs/method.md#conventions and docs/method.md#forward-model.

Nothing here imports a stage: the estimators, the uncertainty, guidance and sharing build on it.

Modules
-------
brdf
    Principled and microfacet parameters and their conversions, Fresnel (Schlick's and the exact
    dielectric's), Smith G1, the BRDF kernel and band limit, the three forward models of the
    paper, the sampling bounds of appendix C.
tables
    The GGX lobe's split-sum albedo, its response to the environment's SH, its per-degree gains,
    Burley's diffuse, their quadratures, nodes and lookups; the tables are shipped in data/.
light
    The light a lobe reads: the fitted light, the environment light of rough lobes, the
    prefiltered environment maps of smooth lobes, Burley's diffuse under the environment.
materials
    Principled texture sets (`MaterialMaps`): reading, writing, resampling.
"""

from freqbrdf.model.brdf import (
    ALPHA_MIN,
    DIELECTRIC_F0,
    MicrofacetParams,
    PrincipledParams,
    alpha_from_roughness,
    band_limit_sigma,
    brdf_kernel,
    constant_fit_coeffs,
    dielectric_eta,
    dielectric_fresnel,
    microfacet_from_principled,
    min_resolvable_alpha,
    min_resolvable_roughness,
    predict_angular,
    predict_power_spectrum,
    predict_sh_coeffs,
    principled_from_microfacet,
    resolvable_degree,
    schlick_fresnel,
    shadowed_light,
    smith_g1_ggx,
    views_needed,
)
from freqbrdf.model.light import (
    PREFILTER_MAX_HEIGHT,
    environment_azimuthal,
    environment_burley_factor,
    environment_filtered_light,
    environment_weight,
    lobe_filtered_light,
    local_environment,
    prefiltered_environment,
    prefiltered_light,
)
from freqbrdf.model.materials import (
    MAP_DESCRIPTIONS,
    MAP_FILES,
    MaterialMaps,
    load_material_maps,
    resize,
    save_material_maps,
)
from freqbrdf.model.tables import (
    ENVIRONMENT_LMAX,
    LOBE_TERMS,
    PREFILTER_STEP,
    burley_diffuse_factor,
    burley_response_table,
    environment_pairs,
    environment_response,
    environment_response_table,
    ggx_lobe_gains,
    integrate_split_sum_table,
    lobe_sh_response,
    split_sum_table,
    split_sum_terms,
    table_nodes,
)

__all__ = [
    "ALPHA_MIN",
    "DIELECTRIC_F0",
    "ENVIRONMENT_LMAX",
    "LOBE_TERMS",
    "MAP_DESCRIPTIONS",
    "MAP_FILES",
    "PREFILTER_MAX_HEIGHT",
    "PREFILTER_STEP",
    "MaterialMaps",
    "MicrofacetParams",
    "PrincipledParams",
    "alpha_from_roughness",
    "band_limit_sigma",
    "brdf_kernel",
    "burley_diffuse_factor",
    "burley_response_table",
    "constant_fit_coeffs",
    "dielectric_eta",
    "dielectric_fresnel",
    "environment_azimuthal",
    "environment_burley_factor",
    "environment_filtered_light",
    "environment_pairs",
    "environment_response",
    "environment_response_table",
    "environment_weight",
    "ggx_lobe_gains",
    "integrate_split_sum_table",
    "load_material_maps",
    "lobe_filtered_light",
    "lobe_sh_response",
    "local_environment",
    "microfacet_from_principled",
    "min_resolvable_alpha",
    "min_resolvable_roughness",
    "predict_angular",
    "predict_power_spectrum",
    "predict_sh_coeffs",
    "prefiltered_environment",
    "prefiltered_light",
    "principled_from_microfacet",
    "resize",
    "resolvable_degree",
    "save_material_maps",
    "schlick_fresnel",
    "shadowed_light",
    "smith_g1_ggx",
    "split_sum_table",
    "split_sum_terms",
    "table_nodes",
    "views_needed",
]
