#version 450
// Mover mask: object-space vertex to world space with the current or previous transform.
#include "common.glsl"
layout(location = 0) in vec3 in_pos;
layout(set = 0, binding = 1) readonly buffer Instances { InstanceData inst[]; };
layout(push_constant) uniform Push { vec4 light_pos; uint use_prev; float widen; } pc;
layout(location = 0) out vec3 v_world;
void main() {
    InstanceData d = inst[gl_InstanceIndex];
    v_world = ((pc.use_prev != 0u ? d.prev_model : d.model) * vec4(in_pos, 1.0)).xyz;
    gl_Position = vec4(v_world, 1.0);
}
