#version 460
#extension GL_GOOGLE_include_directive : require
// HSDT phase 1, latitude scans (paper Algorithm 1 LatitudeScans; CPU mirror
// penumbra_math::hsdt::latitude_scan): one invocation per (map, row theta_i). A forward and a
// backward scan over phi give, for every texel, the column of the nearest occluded texel (low 16
// bits) and of the nearest visible texel (high 16 bits) in the same row (0xFFFF: none), by |dphi|,
// which is exact for the spherical metric (see math/src/hsdt.rs).
#include "avs_maps.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 0) readonly buffer Vis { uint vis[]; };
layout(std430, set = 0, binding = 1) buffer G { uint g[]; };
// r, maps in this dispatch, index of the first map in `vis`
layout(push_constant) uniform Push { uint r; uint n_maps; uint map_offset; uint pad; } pc;

const uint NONE = 0xFFFFu;

uint improve(uint fwd, uint s, uint j) {
    if (s == NONE) return fwd;
    uint dg = fwd == NONE ? 0xFFFFFFFFu : j - fwd;
    return (s - j) < dg ? s : fwd;
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    uint p = gl_GlobalInvocationID.y;
    uint r = pc.r;
    if (i >= r || p >= pc.n_maps) return;
    uint vbase = (p + pc.map_offset) * avs_words_per_map(r);
    uint gbase = (p * r + i) * r;
    uint last_occ = NONE, last_vis = NONE;
    for (uint j = 0u; j < r; j++) {
        if (AVS_VIS_BIT(vis, vbase, i * r + j)) last_vis = j; else last_occ = j;
        g[gbase + j] = last_occ | (last_vis << 16u);
    }
    uint s_occ = NONE, s_vis = NONE;
    for (int jj = int(r) - 1; jj >= 0; jj--) {
        uint j = uint(jj);
        if (AVS_VIS_BIT(vis, vbase, i * r + j)) {
            s_vis = j;
            uint fwd = g[gbase + j];
            g[gbase + j] = improve(fwd & 0xFFFFu, s_occ, j) | (j << 16u);
        } else {
            s_occ = j;
            uint fwd = g[gbase + j];
            g[gbase + j] = j | (improve(fwd >> 16u, s_vis, j) << 16u);
        }
    }
}
