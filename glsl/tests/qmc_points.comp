#version 450
// Test kernel: qmc_2d (glsl/include/qmc.glsl) for `count` consecutive indices from `first` of
// each of `seeds` sequences (passes/src/kernels/qmc.rs, tests/render.rs).
layout(local_size_x = 64) in;
#include "qmc.glsl"

layout(set = 0, binding = 0) readonly buffer Seeds { uint seeds[]; };
// per sequence, per index: the point
layout(set = 0, binding = 1) writeonly buffer Out { vec2 points[]; };

layout(push_constant) uniform Push { uint first; uint count; uint sequences; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count * pc.sequences) return;
    uint s = i / pc.count, k = i % pc.count;
    points[i] = qmc_2d(pc.first + k, seeds[s]);
}
