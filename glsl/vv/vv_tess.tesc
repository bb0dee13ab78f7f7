#version 450
// vv dynamic tessellation shading, control stage: n = 2^round(zeta * Delta) (eq. 17-18).
// Delta = max over the triangle's vertices; an edge takes the max of its two vertices so that
// neighbouring triangles agree on shared edges (no cracks); the inner level uses all three.
#include "vv_data.glsl"

layout(vertices = 3) out;
layout(location = 0) in vec3 v_world[];
layout(location = 1) in vec3 v_normal[];
layout(location = 3) in float v_delta[];
layout(location = 4) in int v_vid[];
layout(location = 6) in int v_tri[];
layout(location = 7) in vec2 v_uv[];
layout(location = 0) out vec3 c_world[];
layout(location = 1) out vec3 c_normal[];
layout(location = 4) out int c_vid[];
layout(location = 6) out int c_tri[];
layout(location = 7) out vec2 c_uv[];

float vv_level(float delta) {
    return clamp(exp2(round(pc.par.y * delta)), 1.0, float(pc.off1.z));
}

void main() {
    c_world[gl_InvocationID] = v_world[gl_InvocationID];
    c_normal[gl_InvocationID] = v_normal[gl_InvocationID];
    c_vid[gl_InvocationID] = v_vid[gl_InvocationID];
    c_tri[gl_InvocationID] = v_tri[gl_InvocationID];
    c_uv[gl_InvocationID] = v_uv[gl_InvocationID];
    if (gl_InvocationID == 0) {
        float d0 = v_delta[0], d1 = v_delta[1], d2 = v_delta[2];
        gl_TessLevelOuter[0] = vv_level(max(d1, d2));
        gl_TessLevelOuter[1] = vv_level(max(d2, d0));
        gl_TessLevelOuter[2] = vv_level(max(d0, d1));
        gl_TessLevelInner[0] = vv_level(max(d0, max(d1, d2)));
    }
}
