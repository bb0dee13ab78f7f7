#version 460
#extension GL_GOOGLE_include_directive : require
// Test and bench shader (tests/hsdt.rs, `penumbra bench hsdt`): the SSDF integrals of
// glsl/include/ssdf_integrate.glsl for (map, lobe) pairs, compared with
// penumbra_math::ssdf_integrate on the CPU / timed per method.
// lobes[q] = (axis.xyz, lambda), params[q] = (mu, cosine ? 1 : 0, map index, methods: 1 = (a),
// 2 = (b), 0 or 3 = both); out[q] = (method (a), method (b)) (0 for a method not run).
layout(local_size_x = 16) in;
layout(std430, set = 0, binding = 0) readonly buffer S { uint ssdf_words[]; };
layout(std430, set = 0, binding = 1) readonly buffer T { float axis_table[]; };
layout(std430, set = 0, binding = 2) readonly buffer L { vec4 lobes[]; };
layout(std430, set = 0, binding = 3) readonly buffer P { vec4 params[]; };
layout(std430, set = 0, binding = 4) writeonly buffer O { vec2 outv[]; };
layout(push_constant) uniform Push { uint r; uint n; } pc;

uint g_map_base;
#define SSDF_FETCH(k) AVS_SSDF(ssdf_words, g_map_base, (k))
#define SSDF_TABLE(i) axis_table[(i)]
#include "ssdf_integrate.glsl"

void main() {
    uint q = gl_GlobalInvocationID.x;
    if (q >= pc.n) return;
    vec4 l = lobes[q];
    vec4 p = params[q];
    g_map_base = uint(p.z) * avs_ssdf_words_per_map(pc.r);
    bool cosine = p.y > 0.5;
    uint methods = uint(p.w) == 0u ? 3u : uint(p.w);
    float a = (methods & 1u) != 0u ? ssdf_visible_axis(l.xyz, l.w, p.x, cosine, pc.r) : 0.0;
    float b = (methods & 2u) != 0u ? ssdf_visible_cells(l.xyz, l.w, p.x, cosine, pc.r) : 0.0;
    outv[q] = vec2(a, b);
}
