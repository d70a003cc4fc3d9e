#version 330 core
// jkatana interactive path, forward: shades every rasterised fragment of the mesh (the windowed
// Viewer, and MSAA frames). The shading itself is in shade.glsl.

in vec3 frag_position;
in vec3 frag_normal;
in vec2 uv_0;

out vec4 frag_color;

#include "shade.glsl"

void main()
{
    frag_color = jk_shade(normalize(frag_normal), normalize(cam_pos - frag_position), uv_0);
}
