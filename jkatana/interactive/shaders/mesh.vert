#version 330 core
// jkatana interactive path: vertex stage. pyrender passes NORMAL_LOC,
// TEXCOORD_0_LOC and INST_M_LOC as defines (it text-replaces their names);
// the blade always has normals and UVs.
layout(location = 0) in vec3 position;
layout(location = NORMAL_LOC) in vec3 normal;
layout(location = TEXCOORD_0_LOC) in vec2 texcoord_0;
layout(location = INST_M_LOC) in mat4 inst_m;

uniform mat4 M;
uniform mat4 V;
uniform mat4 P;

out vec3 frag_position;
out vec3 frag_normal;
out vec2 uv_0;

void main()
{
    mat4 model = M * inst_m;
    vec4 world = model * vec4(position, 1.0);
    gl_Position = P * V * world;
    frag_position = world.xyz;
    frag_normal = normalize(transpose(inverse(mat3(model))) * normal);
    uv_0 = texcoord_0;
}
