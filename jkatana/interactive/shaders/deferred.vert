#version 330 core
// jkatana interactive path, deferred pass 2: one triangle covering the viewport, on the far plane
// (depth 1). With the depth test GL_GREATER against the G-buffer's depth, only pixels where the mesh
// was drawn run deferred.frag.

void main()
{
    vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
    gl_Position = vec4(p, 1.0, 1.0);
}
