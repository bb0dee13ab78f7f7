#version 450
// All-frequency shadow fields, self-occlusion display: every instance with self-visibility maps
// drawn with its vertices' values from sfw_self.comp (slot base[instance] + gl_VertexIndex, the
// mesh's vertex offset folded into base), interpolated across the triangles.
#include "common.glsl"

layout(location = 0) in vec3 in_pos;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Instances { InstanceData inst[]; };
layout(set = 0, binding = 2) readonly buffer Values { vec4 values[]; };
layout(set = 0, binding = 3) readonly buffer Bases { int base[]; };

layout(location = 0) out vec4 v_share;
layout(location = 1) out vec4 v_lights;

void main() {
    InstanceData d = inst[gl_InstanceIndex];
    uint slot = uint(base[gl_InstanceIndex] + gl_VertexIndex);
    v_share = values[2u * slot];
    v_lights = values[2u * slot + 1u];
    gl_Position = cam.view_proj * (d.model * vec4(in_pos, 1.0));
}
