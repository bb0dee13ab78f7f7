#version 450
// vv dynamic tessellation shading, vertex stage: the vertex's radiance under the original and
// the Phong-blurred (alpha 256) lighting (eq. 17 terms), for the control shader's level.
#include "vv_data.glsl"

layout(location = 0) out vec3 v_world;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;
layout(location = 3) out float v_delta;
layout(location = 4) out int v_vid;

void main() {
    int t = gl_VertexIndex / 3, k = gl_VertexIndex % 3;
    int v = vv_tri_vertex(t, k);
    v_world = vv_vert(v, 0);
    v_normal = normalize(vv_vert(v, 1));
    v_albedo = vv_vert(v, 2);
    v_vid = v;
    vec3 i0 = vv_eval_vertex(vv_sat_tex, v, v_world, v_normal, v_albedo);
    vec3 i1 = vv_eval_vertex(vv_sat_blur, v, v_world, v_normal, v_albedo);
    // display-referred difference (times the exposure), eq. 17
    v_delta = abs(dot(i0 - i1, vec3(0.2126, 0.7152, 0.0722))) * cam.env_rot.z;
    gl_Position = cam.view_proj * vec4(v_world, 1.0);
}
