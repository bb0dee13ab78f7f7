#version 460
#extension GL_GOOGLE_include_directive : require
// HSDT phase 2, longitude scans (paper Algorithm 1 LongitudeScans; CPU mirror
// penumbra_math::hsdt::longitude_scan): one invocation per (map, pair of columns phi_j, phi_j+1)
// (a pair so each invocation owns whole fp16x2 output words). Per column and feature (occluded
// texels for the visible ones, visible texels for the occluded ones), the lower envelope of the
// rows' nearest-feature candidates from phase 1 is built by a forward scan with a stack (s, t) and
// read out by a backward scan (Meijster et al. 2002 with spherical distances; exact, see
// math/src/hsdt.rs). Output: signed angular distance in radians as fp16 (avs_maps.glsl layout).
#include "avs_maps.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 0) readonly buffer Vis { uint vis[]; };
layout(std430, set = 0, binding = 1) readonly buffer G { uint g[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Ssdf { uint ssdf[]; };
// r, maps in this dispatch, index of the first map in `vis` and `ssdf`
layout(push_constant) uniform Push { uint r; uint n_maps; uint map_offset; uint pad; } pc;

const uint NONE = 0xFFFFu;
const uint MAXR = 256u;

uint st[MAXR];      // candidate: row (bits 0-7) | nearest-feature column (8-15) | first query row of its region (16-23)
float res[2][MAXR]; // signed distances of the two columns

// sin(k h / 2) and sin((k + 0.5) h) for k < r, per invocation (no workgroup barrier: lavapipe
// runs barrier shaders as coroutines, much slower): the haversine of two texel centres is then
// table lookups.
float s_half[MAXR];
float s_row[MAXR];

float sq(float x) { return x * x; }
uint adiff(uint a, uint b) { return a > b ? a - b : b - a; }

// haversine sin^2(d/2) between texel centres (i1, j1) and (i2, j2)
float havi(uint i1, uint j1, uint i2, uint j2) {
    return sq(s_half[adiff(i1, i2)]) + s_row[i1] * s_row[i2] * sq(s_half[adiff(j1, j2)]);
}

void column(uint p, uint j, uint c, uint vbase) {
    uint r = pc.r;
    float h = float(AVS_PI) / float(r);
    for (uint feat = 0u; feat < 2u; feat++) {
        // feat 0: nearest occluded (for visible texels), 1: nearest visible (for occluded)
        uint shift = feat * 16u;
        int q = -1;
        for (uint u = 0u; u < r; u++) {
            uint gu = (g[(p * r + u) * r + j] >> shift) & 0xFFFFu;
            if (gu == NONE) continue;
            while (q >= 0) {
                uint e = st[q];
                uint sq_ = e & 0xFFu, cs = (e >> 8u) & 0xFFu, tq = e >> 16u;
                if (havi(tq, j, sq_, cs) >= havi(tq, j, u, gu)) q--; else break;
            }
            if (q < 0) {
                q = 0;
                st[0] = u | (gu << 8u);
            } else {
                uint e = st[q];
                uint sq_ = e & 0xFFu, cs = (e >> 8u) & 0xFFu, tq = e >> 16u;
                uint lo = tq + 1u, hi = r;
                while (lo < hi) {
                    uint mid = (lo + hi) / 2u;
                    if (havi(mid, j, u, gu) <= havi(mid, j, sq_, cs)) hi = mid; else lo = mid + 1u;
                }
                if (lo < r) {
                    q++;
                    st[q] = u | (gu << 8u) | (lo << 16u);
                }
            }
        }
        bool want_vis = feat == 0u; // texels whose distance this envelope gives
        for (int ii = int(r) - 1; ii >= 0; ii--) {
            uint i = uint(ii);
            bool v = AVS_VIS_BIT(vis, vbase, i * r + j);
            if (v != want_vis) continue;
            float d;
            if (q < 0) {
                d = float(AVS_NO_BOUNDARY);
            } else {
                while (q > 0 && (st[q] >> 16u) > i) q--;
                uint sq_ = st[q] & 0xFFu, cs = (st[q] >> 8u) & 0xFFu;
                d = avs_angular_distance(vec2((float(i) + 0.5) * h, (float(j) + 0.5) * h),
                                         vec2((float(sq_) + 0.5) * h, (float(cs) + 0.5) * h));
            }
            res[c][i] = v ? d : -d;
        }
    }
}

void main() {
    uint jp = gl_GlobalInvocationID.x;
    uint p = gl_GlobalInvocationID.y;
    uint r = pc.r;
    float h = float(AVS_PI) / float(r);
    if (jp >= r / 2u || p >= pc.n_maps) return;
    for (uint k = 0u; k < r; k++) {
        s_half[k] = avs_sin(0.5 * float(k) * h);
        s_row[k] = avs_sin((float(k) + 0.5) * h);
    }
    uint mp = p + pc.map_offset;
    uint vbase = mp * avs_words_per_map(r);
    column(p, 2u * jp, 0u, vbase);
    column(p, 2u * jp + 1u, 1u, vbase);
    uint obase = mp * avs_ssdf_words_per_map(r);
    for (uint i = 0u; i < r; i++) {
        // texels k = i*r + 2jp (even, low half) and k + 1 share word k / 2
        ssdf[obase + (i * r + 2u * jp) / 2u] = packHalf2x16(vec2(res[0][i], res[1][i]));
    }
}
