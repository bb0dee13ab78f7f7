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

uint st[MAXR];      // candidate row (low 16) | first query row of its region (high 16)
float res[2][MAXR]; // signed distances of the two columns

// haversine sin^2(d/2) between (theta1, phi1) and (theta2, phi2)
float hav(float t1, float p1, float t2, float p2) {
    float a = avs_sin(0.5 * (t1 - t2));
    float b = avs_sin(0.5 * (p1 - p2));
    return a * a + avs_sin(t1) * avs_sin(t2) * b * b;
}

void column(uint p, uint j, uint c, uint vbase) {
    uint r = pc.r;
    float h = float(AVS_PI) / float(r);
    float phi = (float(j) + 0.5) * h;
    for (uint feat = 0u; feat < 2u; feat++) {
        // feat 0: nearest occluded (for visible texels), 1: nearest visible (for occluded)
        uint shift = feat * 16u;
        int q = -1;
        for (uint u = 0u; u < r; u++) {
            uint gu = (g[(p * r + u) * r + j] >> shift) & 0xFFFFu;
            if (gu == NONE) continue;
            float tu = (float(u) + 0.5) * h;
            float pu = (float(gu) + 0.5) * h;
            while (q >= 0) {
                uint sq = st[q] & 0xFFFFu, tq = st[q] >> 16u;
                float ps = (float((g[(p * r + sq) * r + j] >> shift) & 0xFFFFu) + 0.5) * h;
                float tqa = (float(tq) + 0.5) * h;
                if (hav(tqa, phi, (float(sq) + 0.5) * h, ps) >= hav(tqa, phi, tu, pu)) q--; else break;
            }
            if (q < 0) {
                q = 0;
                st[0] = u;
            } else {
                uint sq = st[q] & 0xFFFFu, tq = st[q] >> 16u;
                float ts = (float(sq) + 0.5) * h;
                float ps = (float((g[(p * r + sq) * r + j] >> shift) & 0xFFFFu) + 0.5) * h;
                uint lo = tq + 1u, hi = r;
                while (lo < hi) {
                    uint mid = (lo + hi) / 2u;
                    float tm = (float(mid) + 0.5) * h;
                    if (hav(tm, phi, tu, pu) <= hav(tm, phi, ts, ps)) hi = mid; else lo = mid + 1u;
                }
                if (lo < r) {
                    q++;
                    st[q] = u | (lo << 16u);
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
                uint sq = st[q] & 0xFFFFu;
                float ps = (float((g[(p * r + sq) * r + j] >> shift) & 0xFFFFu) + 0.5) * h;
                d = avs_angular_distance(vec2((float(i) + 0.5) * h, phi), vec2((float(sq) + 0.5) * h, ps));
            }
            res[c][i] = v ? d : -d;
        }
    }
}

void main() {
    uint jp = gl_GlobalInvocationID.x;
    uint p = gl_GlobalInvocationID.y;
    uint r = pc.r;
    if (jp >= r / 2u || p >= pc.n_maps) return;
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
