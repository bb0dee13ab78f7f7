#version 460
// kd-tree build, step 0: the root (pending, all triangles, the scene box) and the counters.
// Counter layout: see passes/src/kdtree.rs (KdStats).
layout(local_size_x = 64) in;
layout(std430, binding = 0) writeonly buffer Nodes { uvec4 nodes[]; };
layout(std430, binding = 1) writeonly buffer Boxes { vec4 boxes[]; };
layout(std430, binding = 2) writeonly buffer Refs { uint refs[]; };
layout(std430, binding = 3) writeonly buffer Counters { uint ctr[]; };
layout(push_constant) uniform Push {
    vec4 lo;   // xyz scene box min, w = triangle count (bits)
    vec4 hi;   // xyz scene box max
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    uint n = floatBitsToUint(pc.lo.w);
    if (i < n) refs[i] = i;
    if (i < 128u) {
        uint v = 0u;
        if (i == 0u) v = n;            // refs used
        if (i == 6u) v = n;            // triangle count
        if (i >= 8u && i < 11u) v = floatBitsToUint(pc.lo[i - 8u]);
        if (i >= 11u && i < 14u) v = floatBitsToUint(pc.hi[i - 11u]);
        if (i == 16u) v = 1u;          // level 0 holds the root
        if (i == 112u) v = 1u;         // large-node list of level 0: the root
        ctr[i] = v;
    }
    if (i == 0u) {
        ctr[128] = 0u;                 // ... whose index is 0
        nodes[0] = uvec4(0u, 4u, 0u, n);
        boxes[0] = vec4(pc.lo.xyz, 0.0);
        boxes[1] = vec4(pc.hi.xyz, 0.0);
    }
}
