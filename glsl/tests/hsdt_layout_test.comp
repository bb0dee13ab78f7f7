#version 460
#extension GL_GOOGLE_include_directive : require
// Test shader (tests/hsdt.rs): evaluates the avs_maps.glsl layout functions so the test can
// compare them with penumbra_math::avs_maps. Invocation k (< r*r, texel (k / r, k % r)) writes
//   out[4k]   = (avs_texel_dir, avs_texel_solid_angle)
//   out[4k+1] = (texel of avs_dir_to_texel(dirs[k]) as floats, found ? 1 : 0,
//                avs_angular_distance(texel k, texel (k * 7919) % (r*r)))
//   out[4k+2] = (avs_frame(dirs[k]).t, 0), out[4k+3] = (avs_frame_hint(dirs[k], +y).t, 0)
#include "avs_maps.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 0) readonly buffer In { vec4 dirs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Out { vec4 outv[]; };
layout(push_constant) uniform Push { uint r; } pc;

void main() {
    uint k = gl_GlobalInvocationID.x;
    uint r = pc.r;
    if (k >= r * r) return;
    uint i = k / r, j = k % r;
    outv[4u * k] = vec4(avs_texel_dir(i, j, r), avs_texel_solid_angle(i, r));
    uvec2 ij;
    bool ok = avs_dir_to_texel(dirs[k].xyz, r, ij);
    uint k2 = (k * 7919u) % (r * r);
    float d = avs_angular_distance(vec2(avs_texel_theta(i, r), avs_texel_phi(j, r)),
                                   vec2(avs_texel_theta(k2 / r, r), avs_texel_phi(k2 % r, r)));
    outv[4u * k + 1u] = vec4(vec2(ij), ok ? 1.0 : 0.0, d);
    outv[4u * k + 2u] = vec4(avs_frame(dirs[k].xyz)[0], 0.0);
    outv[4u * k + 3u] = vec4(avs_frame_hint(dirs[k].xyz, vec3(0.0, 1.0, 0.0))[0], 0.0);
}
