#version 330 core
// jkatana interactive path, deferred pass 2: shades each covered pixel once from the G-buffer
// (shade.glsl), whatever the number of triangles under it.

uniform sampler2D jk_g0;            // (unit normal, u)
uniform sampler2D jk_g1;            // (world position, v)

out vec4 frag_color;

#include "shade.glsl"

void main()
{
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 a = texelFetch(jk_g0, p, 0);
    vec4 b = texelFetch(jk_g1, p, 0);
    frag_color = jk_shade(a.xyz, b.xyz, vec2(a.w, b.w));
}
