#version 450
// vv per-fragment modes: one vertex per triangle corner (non-indexed draw of 3 T vertices).
#include "vv_data.glsl"

layout(location = 0) out vec3 v_world;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_bary;
layout(location = 3) flat out ivec3 v_vids;
layout(location = 4) out vec2 v_uv;

void main() {
    int t = gl_VertexIndex / 3, k = gl_VertexIndex % 3;
    int v = vv_tri_vertex(t, k);
    v_world = vv_vert(v, 0);
    v_normal = vv_vert(v, 1);
    v_uv = vv_vert_uv(v);
    v_bary = vec3(k == 0, k == 1, k == 2);
    v_vids = ivec3(vv_tri_vertex(t, 0), vv_tri_vertex(t, 1), vv_tri_vertex(t, 2));
    gl_Position = cam.view_proj * vec4(v_world, 1.0);
}
