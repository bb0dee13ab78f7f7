#version 450
// ISG per-vertex mode: rasterizes the receivers (world-space vertices from passes/src/isg,
// the same surfaces as the G-buffer) and interpolates the per-vertex visibilities of
// isg_vertex.comp.
#include "common.glsl"

layout(location = 0) in vec3 in_pos;  // world space

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Vis { vec4 vis[]; };

layout(location = 0) out vec4 v_vis;

void main() {
    v_vis = vis[gl_VertexIndex];
    gl_Position = cam.view_proj * vec4(in_pos, 1.0);
}
