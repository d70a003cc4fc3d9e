#version 330 core
// jkatana interactive path, deferred pass 2: a convex polygon on the far plane (depth 1), drawn as a
// triangle fan, that covers every pixel the mesh can cover this frame (glrender's cover: the convex hull
// of the projected bounding boxes of the mesh's visible chunks, grown by a pixel and a half). With the
// depth test GL_GREATER against the G-buffer's depth, only pixels where the mesh was drawn run
// deferred.frag; the polygon keeps llvmpipe from depth-testing the rest of the screen.

uniform vec2 jk_cover[64];          // the polygon's vertices in normalised device coordinates

void main()
{
    gl_Position = vec4(jk_cover[gl_VertexID], 1.0, 1.0);
}
