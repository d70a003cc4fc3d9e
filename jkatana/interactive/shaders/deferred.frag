#version 330 core
// jkatana interactive path, deferred pass 2: shades each covered pixel once from the G-buffer
// (shade.glsl), whatever the number of triangles under it. The view direction is the camera ray through
// the pixel's centre (where the G-buffer pass sampled the surface).

uniform sampler2D jk_g0;            // (octahedral unit normal, u, v)
uniform mat4 jk_inv_vp;             // (P V)⁻¹: clip space → world
uniform vec2 jk_viewport;           // width, height in pixels

out vec4 frag_color;

#include "shade.glsl"

vec3 oct_decode(vec2 e)
{
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    float t = max(-n.z, 0.0);
    n.xy += vec2(n.x >= 0.0 ? -t : t, n.y >= 0.0 ? -t : t);
    return normalize(n);
}

void main()
{
    vec4 g = texelFetch(jk_g0, ivec2(gl_FragCoord.xy), 0);
    vec2 ndc = 2.0 * gl_FragCoord.xy / jk_viewport - 1.0;
    vec4 far = jk_inv_vp * vec4(ndc, 1.0, 1.0);
    frag_color = jk_shade(oct_decode(g.xy), normalize(cam_pos - far.xyz / far.w), g.zw);
}
