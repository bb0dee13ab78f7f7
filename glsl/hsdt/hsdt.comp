#version 460
#extension GL_GOOGLE_include_directive : require
// HSDT (paper section 5, Algorithm 1) in one pass; CPU mirror penumbra_math::hsdt. One invocation
// per (map, pair of columns phi_j, phi_j+1), so each invocation owns whole fp16x2 output words.
//
// Phase 1 (the latitude scans): the column of the nearest occluded and of the nearest visible
// texel in a row, by |dphi| (ties: the lower column), is read off the row's visibility bits where
// phase 2 needs it (findMSB / findLSB on the word holding the texel, then on its neighbours within
// the row), the same answer as the paper's forward and backward scans (penumbra_math::hsdt::
// latitude_scan) without an intermediate buffer: the transform reads r*r/8 bytes and writes the
// SSDF, nothing else.
// Phase 2 (the longitude scans): per column and feature (occluded texels for the visible ones,
// visible texels for the occluded ones) the lower envelope of the rows' candidates (Meijster et al.
// 2002 with spherical distances) built by a forward scan with a stack (s, t): each separator (the
// first query row where the newer candidate is at least as close) in closed form,
// theta* = atan2(-beta, -alpha) (penumbra_math::hsdt::closed_form_separator, which the tests hold
// against bisection on the haversine comparison: they differ only where the two distances agree to
// rounding); read out by one backward scan over the rows that gives each texel the distance to its
// envelope's candidate. Output: signed angular distance in radians as fp16 (avs_maps.glsl).
// On lavapipe the pushes cost most (r = 128: about 60 % of the pass): fewer per-lane private-array
// accesses (each envelope's top in registers, no array indexed by a per-lane value but the stacks)
// and a closed form instead of a bisection took the pass from 724 to about 270 us per map.
#include "avs_maps.glsl"

layout(local_size_x = 32) in;
layout(std430, set = 0, binding = 0) readonly buffer Vis { uint vis[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Ssdf { uint ssdf[]; };
// r, maps in this dispatch, index of the first map in `vis` and `ssdf`
layout(push_constant) uniform Push { uint r; uint n_maps; uint map_offset; uint pad; } pc;

const uint NONE = 0xFFFFu;
const uint MAXR = 256u;

float sq(float x) { return x * x; }

// Four envelopes per invocation, e = 2 c + f: column 2 jp + c, feature f (0: the nearest occluded
// texel, for visible texels; 1: the nearest visible texel, for occluded ones). Entry: candidate
// row (bits 0-7) | its nearest-feature column (8-15) | first query row of its region (16-23).
// Each envelope's top entry lives in registers (tx, and its haversine weight tw = sin(theta_s)
// sin^2(dphi / 2): for column j, hav(i) = sin^2((theta_i - theta_s) / 2) + sin(theta_i) tw), the
// entries below it in st[e][0 .. top - 1] (llvmpipe's private arrays are scattered and gathered
// per lane: the top in registers halves those accesses).
uint st[4][MAXR];
uint tx[4];
float tw[4];
int top[4];
float h;
uint vbase;

// A candidate's haversine weight for column j: sin(theta_row) sin^2((j - col) h / 2), s_row =
// sin(theta_row).
float weight(float s_row, uint j, uint col) { return s_row * sq(avs_sin(0.5 * h * (float(j) - float(col)))); }
// The haversine weight of stack entry x (row, column) for column j.
float cand_w(uint x, uint j) { return weight(avs_sin((float(x & 0xFFu) + 0.5) * h), j, (x >> 8u) & 0xFFu); }

uint feature_word(uint w, bool want_vis) {
    uint x = vis[vbase + w];
    return want_vis ? x : ~x;
}

// Column of the texel of row u nearest to column j by |dphi| (ties: the lower column) whose
// visibility is `want_vis`, or NONE; `x0` = the map's word holding texel (u, j), raw.
uint nearest_in_row(uint u, uint j, bool want_vis, uint x0) {
    uint r = pc.r;
    uint start = u * r, k = start + j, end = start + r;
    uint raw = want_vis ? x0 : ~x0;
    uint below = NONE, above = NONE;
    // at or below column j
    uint w = k >> 5u;
    uint x = raw & ((2u << (k & 31u)) - 1u);
    while (x == 0u && w > (start >> 5u)) {
        w--;
        x = feature_word(w, want_vis);
    }
    if (x != 0u) {
        uint b = w * 32u + uint(findMSB(x));
        if (b >= start) below = b - start;
    }
    if (below == j) return j;
    // above column j
    w = k >> 5u;
    x = raw & ~((2u << (k & 31u)) - 1u);
    while (x == 0u && w < ((end - 1u) >> 5u)) {
        w++;
        x = feature_word(w, want_vis);
    }
    if (x != 0u) {
        uint b = w * 32u + uint(findLSB(x));
        if (b < end) above = b - start;
    }
    if (below == NONE) return above;
    if (above == NONE) return below;
    return (j - below) <= (above - j) ? below : above;
}

// hav_u(i) - hav_s(i) = alpha sin(theta_i) - beta cos(theta_i) for an older candidate s (row s, weight
// ws) and a newer one u (row u > s, weight wu): sin^2 a - sin^2 b = sin(a + b) sin(a - b) with
// a + b = theta_i - m, m = (theta_s + theta_u) / 2, a - b = (theta_s - theta_u) / 2 = sg. Every term is a
// product of small exact factors, so the sign keeps f32's relative precision at tiny distances.
vec2 pair_coeffs(uint s, float ws, uint u, float wu) {
    float m = 0.5 * float(s + u + 1u) * h;
    float sg = avs_sin(0.5 * h * (float(s) - float(u)));
    return vec2(avs_sin(0.5 * float(AVS_PI) - m) * sg + (wu - ws), avs_sin(m) * sg);
}
// The first row where the newer candidate is at least as close: alpha sin(theta) - beta cos(theta)
// <= 0 (beta < 0) for theta >= theta* = atan2(-beta, -alpha). The decision errs only where the
// two distances agree to f32 rounding (see math/src/hsdt.rs), so no row-by-row check is needed.
uint separator(vec2 ab) {
    float th = avs_atan2_upper(-ab.y, -ab.x);
    return uint(max(ceil(th / h - 0.5), 0.0));
}

// Adds row u's candidate (nearest-feature column gu; su = sin(theta_u)) to envelope e of column j.
void push(uint e, uint j, uint u, uint gu, float su) {
    float wu = weight(su, j, gu);
    int q = top[e];
    // a feature texel of the column right below the top's (both at dphi = 0): the separator is
    // row u itself and nothing pops (the top is the closer one at and above its own row)
    if (q >= 0 && wu == 0.0 && tw[e] == 0.0 && (tx[e] & 0xFFu) + 1u == u) {
        st[e][q] = tx[e];
        top[e] = q + 1;
        tx[e] = u | (gu << 8u) | (u << 16u);
        return;
    }
    uint sep = 0u;
    // pop the candidates u beats (or ties) at the start of their region
    while (q >= 0) {
        sep = separator(pair_coeffs(tx[e] & 0xFFu, tw[e], u, wu));
        if (sep > (tx[e] >> 16u)) break;
        q--;
        if (q >= 0) {
            tx[e] = st[e][q];
            tw[e] = cand_w(tx[e], j);
        }
    }
    if (q < 0) {
        tx[e] = u | (gu << 8u);
        tw[e] = wu;
        top[e] = 0;
        return;
    }
    if (sep < pc.r) {
        st[e][q] = tx[e];
        q++;
        tx[e] = u | (gu << 8u) | (sep << 16u);
        tw[e] = wu;
    }
    top[e] = q;
}

// Row u's candidate for envelope e (feature e & 1: 0 the nearest occluded texel, 1 the nearest
// visible) of column j, if the row has one; x0 = the map's word holding texel (u, j).
void add_row(uint e, uint j, uint u, uint x0, float su) {
    uint g = nearest_in_row(u, j, (e & 1u) == 1u, x0);
    if (g != NONE) push(e, j, u, g, su);
}

// Moves envelope e's top down to the candidate of row i (rows visited downwards).
void descend(uint e, uint j, uint i) {
    int q = top[e];
    if (q <= 0 || (tx[e] >> 16u) <= i) return;
    while (q > 0 && (tx[e] >> 16u) > i) {
        q--;
        tx[e] = st[e][q];
    }
    tw[e] = cand_w(tx[e], j);
    top[e] = q;
}

// Distance from texel row i (sin(theta_i) = si) to the candidate x of weight w: hav = sin^2(dtheta
// / 2) + si w, and c = cos^2(d / 2) = 1 - hav without cancellation.
float distance_to(uint x, float w, uint i, float si) {
    float a = 0.5 * h * (float(i) - float(x & 0xFFu));
    float ww = si * w;
    float s1 = avs_sin(a);
    float hv = s1 * s1 + ww;
    if (hv <= 0.5) return 2.0 * avs_asin(sqrt(clamp(hv, 0.0, 1.0)));
    float c1 = avs_sin(0.5 * float(AVS_PI) - abs(a));
    return float(AVS_PI) - 2.0 * avs_asin(sqrt(clamp(c1 * c1 - ww, 0.0, 1.0)));
}

void main() {
    uint jp = gl_GlobalInvocationID.x;
    uint p = gl_GlobalInvocationID.y;
    uint r = pc.r;
    if (jp >= r / 2u || p >= pc.n_maps) return;
    h = float(AVS_PI) / float(r);
    uint mp = p + pc.map_offset;
    vbase = mp * avs_words_per_map(r);
    uint j0 = 2u * jp, j1 = j0 + 1u;
    top[0] = -1;
    top[1] = -1;
    top[2] = -1;
    top[3] = -1;
    for (uint u = 0u; u < r; u++) {
        uint x0 = vis[vbase + ((u * r + j0) >> 5u)];
        float su = avs_sin((float(u) + 0.5) * h);
        add_row(0u, j0, u, x0, su);
        add_row(1u, j0, u, x0, su);
        add_row(2u, j1, u, x0, su);
        add_row(3u, j1, u, x0, su);
    }
    uint obase = mp * avs_ssdf_words_per_map(r);
    for (int ii = int(r) - 1; ii >= 0; ii--) {
        uint i = uint(ii);
        uint k = i * r + j0;
        uint word = vis[vbase + (k >> 5u)];
        float si = avs_sin((float(i) + 0.5) * h);
        bool v0 = ((word >> (k & 31u)) & 1u) == 1u;
        bool v1 = ((word >> ((k + 1u) & 31u)) & 1u) == 1u;
        descend(0u, j0, i);
        descend(1u, j0, i);
        descend(2u, j1, i);
        descend(3u, j1, i);
        float d0 = (v0 ? top[0] : top[1]) < 0 ? float(AVS_NO_BOUNDARY) : distance_to(v0 ? tx[0] : tx[1], v0 ? tw[0] : tw[1], i, si);
        float d1 = (v1 ? top[2] : top[3]) < 0 ? float(AVS_NO_BOUNDARY) : distance_to(v1 ? tx[2] : tx[3], v1 ? tw[2] : tw[3], i, si);
        ssdf[obase + k / 2u] = packHalf2x16(vec2(v0 ? d0 : -d0, v1 ? d1 : -d1));
    }
}
