#version 330 core
// jkatana interactive path, deferred pass 1 (with mesh.vert): the G-buffer, one RGBA32F target: the unit
// normal in octahedral coordinates (Cigolle et al. 2014, "A Survey of Efficient Representations for
// Independent Unit Vectors", JCGT 3(2)) and the map coordinates (u, v). The shading pass needs no position:
// the view direction is the pixel's camera ray. No shading here, so llvmpipe's cost per 4×4 block that a
// small triangle touches is a few stores, not the whole shader.

in vec3 frag_position;
in vec3 frag_normal;
in vec2 uv_0;

layout(location = 0) out vec4 g_normal_uv;

vec2 oct_encode(vec3 n)
{
    vec2 p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    return n.z >= 0.0 ? p : (1.0 - abs(p.yx)) * vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
}

void main()
{
    g_normal_uv = vec4(oct_encode(normalize(frag_normal)), uv_0);
}
