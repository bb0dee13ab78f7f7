#version 450
#include "common.glsl"

layout(location = 0) in vec3 in_pos;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Instances { InstanceData inst[]; };

layout(location = 0) out vec3 v_world;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec2 v_uv;
layout(location = 3) out vec4 v_clip;
layout(location = 4) out vec4 v_prev_clip;
layout(location = 5) flat out uvec2 v_ids;

void main() {
    InstanceData d = inst[gl_InstanceIndex];
    vec4 world = d.model * vec4(in_pos, 1.0);
    v_world = world.xyz;
    v_normal = mat3(d.normal_matrix) * in_normal;
    v_uv = in_uv;
    v_clip = cam.view_proj * world;
    v_prev_clip = cam.prev_view_proj * (d.prev_model * vec4(in_pos, 1.0));
    v_ids = d.ids.xy;
    gl_Position = v_clip;
}
