#version 450
// vv dynamic tessellation shading, evaluation stage: radiance at every tessellated vertex,
// with the interpolated vectorized visibility (eq. 21, mode 2) or three evaluations blended
// (eq. 19, mode 3); fragments interpolate it.
#include "vv_data.glsl"

layout(triangles, equal_spacing, ccw) in;
layout(location = 0) in vec3 c_world[];
layout(location = 1) in vec3 c_normal[];
layout(location = 4) in int c_vid[];
// the model triangle from the vertex stage: lavapipe's gl_PrimitiveID here is not the patch
// index of the draw for the bunny (eq. 21 read other triangles' loops: 17.5 dB at zeta = 1
// where the corners equal eq. 19's 22.5 dB)
layout(location = 6) in int c_tri[];
layout(location = 7) in vec2 c_uv[];
layout(location = 0) out vec3 e_color;

void main() {
    vec3 l = gl_TessCoord;
    vec3 s = l.x * c_world[0] + l.y * c_world[1] + l.z * c_world[2];
    vec3 n = normalize(l.x * c_normal[0] + l.y * c_normal[1] + l.z * c_normal[2]);
    vec3 ng = cross(c_world[1] - c_world[0], c_world[2] - c_world[0]);
    if (dot(ng, ng) > 1e-30) vv_face_normal = normalize(dot(ng, n) < 0.0 ? -ng : ng);
    // the material (texture maps) at the tessellated vertex (fragments interpolate the radiance)
    vec2 uv = l.x * c_uv[0] + l.y * c_uv[1] + l.z * c_uv[2];
    MaterialData m = vv_material(c_vid[0], uv);
    bool three = pc.sat.w != 2 || vv_tri_fallback(c_tri[0]);
    e_color = vv_eval_on_triangle(vv_sat_tex, three, c_tri[0], ivec3(c_vid[0], c_vid[1], c_vid[2]), l, s, n, m);
    gl_Position = cam.view_proj * vec4(s, 1.0);
}
