#version 460
#extension GL_GOOGLE_include_directive : require
// avs's key_filter: the environment's key lights' diffuse light, whose shadows avs traces with 9
// rays per pixel (flat bands in a wide penumbra with the fixed pattern, grain with key_pattern =
// stratified), filtered over the screen before it is added to the rest of the pixel
// (avs_shade.comp's `hdr`, `key_out` and `key_aux`). The filter's width follows the penumbra's,
// as ray-traced soft-shadow denoisers do (Boksansky, Wimmer and Bittner, Ray Tracing Gems ch.
// 13): a light of angular radius a (tangent) behind occluders at distance t casts a penumbra
// about 2 a t wide, so each pixel's visible share v is averaged with a Gaussian of standard
// deviation a t / 8 in pixels of the pixel's footprint at its distance (SIGMA_SCALE: a sixteenth
// of the width; a quarter and a tenth blurred the 160 x 120 matrix's narrow penumbrae), within
// `radius` pixels, over neighbours on the pixel's plane (the offset's component along its
// normal, over the offset's length), with a similar normal and lit by the key lights. t is the
// largest of the 3 x 3 neighbourhood's mean hit distances, so a pixel whose rays all passed next
// to one whose rays hit is filtered too; where the 3 x 3 neighbourhood's shares all agree (lit,
// umbra) nothing is filtered, and a contact shadow (t near 0) keeps its edge.
// out = hdr + key.rgb x the filtered v.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
#define SIGMA_SCALE 0.125

layout(set = 0, binding = 0) uniform sampler2D gb_position;
layout(set = 0, binding = 1) uniform sampler2D gb_normal;
layout(set = 0, binding = 2) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D base;
layout(set = 0, binding = 4, rgba32f) uniform readonly image2D key_in;
layout(set = 0, binding = 5, rgba32f) uniform readonly image2D key_aux;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D out_hdr;
layout(push_constant) uniform Push {
    vec3 eye;
    float per_distance;  // a pixel's width at distance 1 (2 tan(fov / 2) / height)
    int radius;          // the window's largest radius in pixels
} pc;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(out_hdr);
    if (px.x >= size.x || px.y >= size.y) return;
    vec4 b = imageLoad(base, px);
    vec4 k = imageLoad(key_in, px);
    vec3 unfiltered = b.rgb + k.rgb * k.a;
    if (texelFetch(gb_uv_mat, px, 0).w < 0.5 || max(k.r, max(k.g, k.b)) <= 0.0) {
        imageStore(out_hdr, px, vec4(unfiltered, 1.0));
        return;
    }
    float t = 0.0, vmin = k.a, vmax = k.a;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
            t = max(t, imageLoad(key_aux, q).x);
            float v = imageLoad(key_in, q).a;
            vmin = min(vmin, v);
            vmax = max(vmax, v);
        }
    }
    vec3 pos = texelFetch(gb_position, px, 0).xyz;
    float footprint = max(length(pos - pc.eye) * pc.per_distance, 1e-6);
    float sigma = SIGMA_SCALE * imageLoad(key_aux, px).y * t / footprint;
    int r = min(int(ceil(2.0 * sigma)), clamp(pc.radius, 0, 8));
    if (vmax <= vmin || t <= 0.0 || r < 1) {
        imageStore(out_hdr, px, vec4(unfiltered, 1.0));
        return;
    }
    vec3 n = oct_decode(texelFetch(gb_normal, px, 0).xy);
    float inv2s2 = 1.0 / (2.0 * sigma * sigma);
    float num = 0.0, den = 0.0;
    for (int dy = -r; dy <= r; ++dy) {
        for (int dx = -r; dx <= r; ++dx) {
            ivec2 q = px + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
            if (texelFetch(gb_uv_mat, q, 0).w < 0.5) continue;
            vec4 kq = imageLoad(key_in, q);
            if (max(kq.r, max(kq.g, kq.b)) <= 0.0) continue;
            vec3 d = texelFetch(gb_position, q, 0).xyz - pos;
            float len = length(d);
            float plane = len > 0.0 ? abs(dot(n, d)) / len : 0.0;
            float nd = max(dot(n, oct_decode(texelFetch(gb_normal, q, 0).xy)), 0.0);
            float w = exp(-float(dx * dx + dy * dy) * inv2s2 - plane / 0.1) * pow(nd, 16.0);
            num += w * kq.a;
            den += w;
        }
    }
    float v = den > 0.0 ? num / den : k.a;
    imageStore(out_hdr, px, vec4(b.rgb + k.rgb * v, 1.0));
}
