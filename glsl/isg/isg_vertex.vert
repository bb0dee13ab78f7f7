#version 450
// ISG per-vertex mode: rasterizes the receivers (world-space vertices from passes/src/isg,
// the same surfaces as the G-buffer) and interpolates the per-vertex visibilities of
// isg_vertex.comp. Drawn unindexed, three invocations per triangle, each reading its
// triangle's three corners: a triangle whose corners' visibilities differ by more than
// `pixel_refine` (any channel: diffuse r, g, b or glossy a) writes -1 over its pixels, which the
// shading pass then evaluates per pixel (an interpolated penumbra or glossy visibility that
// jumps across the triangle is where per-vertex interpolation is wrong).
#include "common.glsl"

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Vis { vec4 vis[]; };
// 3 per vertex: world position + material index, world normal + flags, tangent (isg_vertex.comp)
layout(set = 0, binding = 2) readonly buffer Verts { vec4 verts[]; };
layout(set = 0, binding = 3) readonly buffer Indices { uint indices[]; };

layout(push_constant) uniform Push {
    float pixel_refine;
} pc;

layout(location = 0) out vec4 v_vis;

void main() {
    uint corner = uint(gl_VertexIndex);
    uint first = corner - corner % 3u;
    vec4 a = vis[indices[first]], b = vis[indices[first + 1u]], c = vis[indices[first + 2u]];
    vec4 spread = max(max(a, b), c) - min(min(a, b), c);
    float most = max(max(spread.r, spread.g), max(spread.b, spread.a));
    uint i = indices[corner];
    v_vis = most > pc.pixel_refine ? vec4(-1.0) : vis[i];
    gl_Position = cam.view_proj * vec4(verts[3u * i].xyz, 1.0);
}
