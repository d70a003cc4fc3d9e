#version 330 core
// jkatana interactive path, deferred pass 1 (with mesh.vert): the G-buffer. Two RGBA32F targets:
// (unit normal, u) and (world position, v). No shading here, so llvmpipe's cost per 4×4 block that a
// small triangle touches is a few stores, not the whole shader.

in vec3 frag_position;
in vec3 frag_normal;
in vec2 uv_0;

layout(location = 0) out vec4 g_normal_u;
layout(location = 1) out vec4 g_position_v;

void main()
{
    g_normal_u = vec4(normalize(frag_normal), uv_0.x);
    g_position_v = vec4(frag_position, uv_0.y);
}
