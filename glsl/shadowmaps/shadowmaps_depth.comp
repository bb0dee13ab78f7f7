#version 460
#extension GL_GOOGLE_include_directive : require
// Shadow-map baseline, depth maps: K orthographic depth maps along environment directions,
// rendered by casting one closest-hit ray per texel centre through the kd-tree (the samples a
// rasterizer takes at pixel centres). depth[k][y][x] = distance from the map's near plane to the
// first surface (3e38 where the ray escapes).
layout(local_size_x = 8, local_size_y = 8) in;
layout(std430, binding = 0) readonly buffer Tris { vec4 kd_tris[]; };
layout(std430, binding = 1) readonly buffer Nodes { uvec4 kd_nodes[]; };
layout(std430, binding = 2) readonly buffer Refs { uint kd_refs[]; };
layout(std430, binding = 3) readonly buffer Header { uint kd_hdr[]; };
// per map: (dir towards the light, 0), (weight rgb, 0), (right, 0), (up, 0)
layout(std430, binding = 4) readonly buffer Maps { vec4 maps[]; };
layout(std430, binding = 5) writeonly buffer Depth { float depth[]; };
layout(push_constant) uniform Push {
    uvec4 size_count;   // S, K
    vec4 sphere;        // scene bounding sphere centre, radius
} pc;

#define KD_TRI(i) kd_tris[i]
#define KD_NODE(i) kd_nodes[i]
#define KD_REF(i) kd_refs[i]
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"

void main() {
    uint s = pc.size_count.x, k = gl_GlobalInvocationID.z;
    uvec2 px = gl_GlobalInvocationID.xy;
    if (px.x >= s || px.y >= s || k >= pc.size_count.y) return;
    vec3 wi = maps[4u * k].xyz, right = maps[4u * k + 2u].xyz, up = maps[4u * k + 3u].xyz;
    float r = pc.sphere.w;
    vec2 uv = (vec2(px) + 0.5) / float(s) * 2.0 - 1.0;
    vec3 o = pc.sphere.xyz + wi * (1.01 * r) + (right * uv.x + up * uv.y) * r;
    KdHit h = kd_trace(o, -wi, 0.0, 3.0e38, false);
    depth[(k * s + px.y) * s + px.x] = h.t < 0.0 ? 3.0e38 : h.t;
}
