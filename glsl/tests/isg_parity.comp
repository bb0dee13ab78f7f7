#version 450
// Test kernel: isg_visible (glsl/include/isg.glsl) for a list of queries, compared with
// penumbra_math::isg::visible_fraction_with_triangles on the CPU (passes/src/isg::gpu_visibility,
// tests/isg.rs).
layout(local_size_x = 64) in;

layout(set = 0, binding = 0) readonly buffer Queries { vec4 q[]; };  // 3 per query: p, n, axis + gamma
layout(set = 0, binding = 1) writeonly buffer Out { float vis[]; };
#define ISG_TABLE_BINDING 2
#define ISG_NODES_BINDING 3
#define ISG_TRIS_BINDING 4
#define ISG_TRI_NODES_BINDING 5
#define ISG_MAX_SIDE 32
#include "isg.glsl"

layout(push_constant) uniform Push {
    uint count;
    int node_count;
    int tri_node_count;
    int patch_side;
    float lod;
    uint flags;  // bit 4: isg_paper_fit, bit 5: isg_paper_rule
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    isg_paper_fit = (pc.flags & 16u) != 0u;
    isg_paper_rule = (pc.flags & 32u) != 0u;
    vec3 p = q[3u * i].xyz, n = q[3u * i + 1u].xyz;
    vec4 ag = q[3u * i + 2u];
    vis[i] = isg_visible(p, n, ag.xyz, ag.w, pc.node_count, pc.tri_node_count, pc.patch_side, pc.lod);
}
