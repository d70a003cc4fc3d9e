#version 330 core
// jkatana interactive path: the environment behind the blade. Drawn on the far plane where the
// G-buffer pass left depth at 1; the view ray's direction through each pixel looks the environment up
// at the sharpest prefiltered level, with the basis coefficients of a flat spectrum (radiance XYZ), and
// the caps split off the map (shade.glsl's JK_CAPS) through that level's kernel.

uniform mat4 jk_inv_vp;             // (P V)⁻¹: clip space → world
uniform vec2 jk_viewport;           // width, height in pixels
uniform vec4 jk_bg_coef;            // a_r = Σ_λ b_r(λ): the constant 1 on the Fresnel basis

out vec4 frag_color;

#include "shade.glsl"

void main()
{
    vec2 ndc = 2.0 * gl_FragCoord.xy / jk_viewport - 1.0;
    vec4 far = jk_inv_vp * vec4(ndc, 1.0, 1.0);
    vec3 d = normalize(far.xyz / far.w - cam_pos);
    vec3 de = jk_env_rot * d;
    vec3 xyz = env_xyz(de, 0.5 / jk_n_levels, jk_bg_coef);
#if JK_CAPS > 0
    // the caps split off the map, through the same sharpest level's kernel
    xyz += jk_caps_xyz(jk_bg_coef, de, vec3(0.0), vec3(0.0), vec2(0.69314718 * exp(-2.0 * jk_log_mu_first)));
#endif
    vec3 rgb = max(jk_xyz_to_rgb * (jk_exposure * xyz), 0.0);
    frag_color = vec4(encode1(rgb.r), encode1(rgb.g), encode1(rgb.b), 1.0);
}
