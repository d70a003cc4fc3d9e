"""Pure reflectance models (JAX): Fresnel, facet distributions, shadowing, the paper's models."""

from jkatana.models.fresnel import (
    fresnel_conductor as fresnel_conductor,
    fresnel_dielectric as fresnel_dielectric,
    fresnel_schlick as fresnel_schlick,
    normal_incidence as normal_incidence,
)
from jkatana.models.geometry import (
    facet_angle as facet_angle,
    half_vector_cos as half_vector_cos,
    half_vector_terms as half_vector_terms,
    in_plane as in_plane,
    in_plane_angles as in_plane_angles,
)
from jkatana.models.microfacet import (
    beckmann as beckmann,
    beckmann_phi as beckmann_phi,
    gaussian_facet as gaussian_facet,
    gaussian_normalisation as gaussian_normalisation,
    smith_beckmann as smith_beckmann,
    smith_g1_beckmann as smith_g1_beckmann,
    vcavity as vcavity,
    vcavity_over_cos as vcavity_over_cos,
)
from jkatana.models.reflectance import (
    PAPER_HAMON as PAPER_HAMON,
    PAPER_HIRAJI as PAPER_HIRAJI,
    Conductor as Conductor,
    Hamon as Hamon,
    Hiraji as Hiraji,
    blend as blend,
    paper_models as paper_models,
)
from jkatana.models.lobes import (
    GGX as GGX,
    GTR as GTR,
    LOBES as LOBES,
    Beckmann as Beckmann,
    Gaussian as Gaussian,
    GaussianVCavity as GaussianVCavity,
    Lobe as Lobe,
    Mixture as Mixture,
    lobe_from_params as lobe_from_params,
)
