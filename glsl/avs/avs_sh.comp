#version 460
#extension GL_GOOGLE_include_directive : require
// SH16 projection of visibility maps over world directions (Wang et al., section 4.3; CPU mirror
// penumbra_math::avs_sampling::sh16_project): one workgroup per batch entry, the map at its slot.
// It also marks a buried point (no visible direction: DC not above 0, avs_sampling::buried) in
// its normal's w, which avs_gather.glsl reads.
#include "avs_maps.glsl"
#include "sh16.glsl"

layout(local_size_x = 64) in;
layout(std430, binding = 0) buffer Points { vec4 pts[]; };
layout(std430, binding = 1) readonly buffer Batch { uint batch[]; };
layout(std430, binding = 2) readonly buffer Vis { uint vis[]; };
layout(std430, binding = 3) writeonly buffer Sh { float sh_out[]; };
layout(push_constant) uniform Push { uint r; uint count; } pc;

shared float partial[64][16];

void main() {
    uint tid = gl_LocalInvocationID.x;
    uint words = avs_words_per_map(pc.r);
    for (uint e = gl_WorkGroupID.x; e < pc.count; e += gl_NumWorkGroups.x) {
        uint slot = batch[e];
        vec3 t = pts[3u * slot + 1u].xyz, n = pts[3u * slot + 2u].xyz;
        mat3 fr = mat3(t, cross(n, t), n);
        float acc[16];
        for (int c = 0; c < 16; ++c) acc[c] = 0.0;
        for (uint k = tid; k < pc.r * pc.r; k += 64u) {
            if (!AVS_VIS_BIT(vis, slot * words, k)) continue;
            uint i = k / pc.r, j = k % pc.r;
            float y[16];
            sh16_basis(fr * avs_texel_dir(i, j, pc.r), y);
            float sa = avs_texel_solid_angle(i, pc.r);
            for (int c = 0; c < 16; ++c) acc[c] += y[c] * sa;
        }
        for (int c = 0; c < 16; ++c) partial[tid][c] = acc[c];
        barrier();
        if (tid < 16u) {
            float s = 0.0;
            for (uint q = 0u; q < 64u; ++q) s += partial[q][tid];
            sh_out[16u * e + tid] = s;
            if (tid == 0u) pts[3u * slot + 2u].w = (s > 0.0) ? 0.0 : 1.0;
        }
        barrier();
    }
}
