"""Lighting: spectral environment maps, RGB upsampling, the Hosek–Wilkie sky, sampling, prefiltering,
compact sources (suns) split off as cap lights and their cap × lobe quadrature.

See :mod:`jkatana.light.envmap` for the orientation convention (Y up, image
centre looks along −Z, row 0 = zenith).
"""

from jkatana.light.capquad import (
    cap_coverage as cap_coverage,
    cap_integral as cap_integral,
    cap_point_integral as cap_point_integral,
    reflected_cap_radiance as reflected_cap_radiance,
)
from jkatana.light.envmap import (
    EnvMap as EnvMap,
    direction_to_uv as direction_to_uv,
    load_envmap as load_envmap,
    texel_directions as texel_directions,
    texel_solid_angles as texel_solid_angles,
    uv_to_direction as uv_to_direction,
)
from jkatana.light.fresnel_basis import FresnelBasis as FresnelBasis, fresnel_basis as fresnel_basis
from jkatana.light.prefilter import (
    PrefilteredEnv as PrefilteredEnv,
    prefilter as prefilter,
    project_on_basis as project_on_basis,
)
from jkatana.light.sampling import (
    EnvSampler as EnvSampler,
    frame_from_normal as frame_from_normal,
    mis_weight as mis_weight,
    reflected_radiance as reflected_radiance,
)
from jkatana.light.sky import (
    hosek_wilkie_sky as hosek_wilkie_sky,
    sun_direction as sun_direction,
    sun_position as sun_position,
)
from jkatana.light.sun import (
    SunCap as SunCap,
    SunSplit as SunSplit,
    find_compact_sources as find_compact_sources,
    split_compact_sources as split_compact_sources,
    split_sky_sun as split_sky_sun,
)
from jkatana.light.spectral_exr import read_spectral_exr as read_spectral_exr, write_spectral_exr as write_spectral_exr
from jkatana.light.upsampling import (
    UPSAMPLING_METHODS as UPSAMPLING_METHODS,
    rgb_to_spectrum as rgb_to_spectrum,
    round_trip_error as round_trip_error,
)
