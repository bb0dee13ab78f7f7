#version 460
#extension GL_GOOGLE_include_directive : require
// The compute ray tracer: one ray per invocation through the kd-tree (include/kdtree.glsl).
// Ray i: texels 2i = (origin, tmin), 2i+1 = (direction, tmax) as float bits (a texel buffer:
// one gather per texel on a CPU device); direction need not be unit.
// Hit i: (t, b1, b2, triangle index as float bits); t < 0 is a miss. Any-hit mode reports the
// first hit found (not the closest), whose t is only meaningful as "occluded".
layout(local_size_x = 64) in;
layout(binding = 0) uniform usamplerBuffer kd_tris;
layout(binding = 1) uniform usamplerBuffer kd_nodes;
layout(binding = 2) uniform usamplerBuffer kd_refs;
layout(std430, binding = 3) readonly buffer Header { uint kd_hdr[]; };
layout(binding = 4) uniform usamplerBuffer rays;
layout(std430, binding = 5) writeonly buffer Hits { vec4 hits[]; };
layout(push_constant) uniform Push { uint count; uint any_hit; } pc;

#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"

void main() {
    uint stride = gl_NumWorkGroups.x * 64u;
    for (uint i = gl_GlobalInvocationID.x; i < pc.count; i += stride) {
        vec4 a = uintBitsToFloat(texelFetch(rays, int(2u * i))), b = uintBitsToFloat(texelFetch(rays, int(2u * i + 1u)));
        KdHit h = kd_trace(a.xyz, b.xyz, a.w, b.w, pc.any_hit != 0u);
        hits[i] = vec4(h.t, h.b1, h.b2, uintBitsToFloat(h.tri));
    }
}
