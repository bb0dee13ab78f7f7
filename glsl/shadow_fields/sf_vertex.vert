#version 450
// Shadow fields, per-vertex display: draws every instance with the radiance its visible
// vertices got from sf_points.comp (slot base[instance] + gl_VertexIndex, the vertex offset of
// the mesh folded into base), interpolated across the triangles (Gouraud, as the paper).
#include "common.glsl"

layout(location = 0) in vec3 in_pos;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Instances { InstanceData inst[]; };
layout(set = 0, binding = 2) readonly buffer Radiance { vec4 radiance[]; };
layout(set = 0, binding = 3) readonly buffer Bases { int base[]; };

layout(location = 0) out vec3 v_radiance;

void main() {
    InstanceData d = inst[gl_InstanceIndex];
    v_radiance = radiance[uint(base[gl_InstanceIndex] + gl_VertexIndex)].rgb;
    gl_Position = cam.view_proj * (d.model * vec4(in_pos, 1.0));
}
