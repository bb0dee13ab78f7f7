#version 450
// Exposure, ACES filmic fit (Narkowicz 2015) and the sRGB transfer function, into an 8-bit
// UNORM image holding sRGB-encoded values.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(push_constant) uniform Push { float exposure; } pc;
layout(set = 0, binding = 0) uniform sampler2D hdr;
layout(set = 0, binding = 1, rgba8) uniform writeonly image2D ldr;

vec3 aces(vec3 x) {
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

vec3 srgb_oetf(vec3 c) {
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, greaterThan(c, vec3(0.0031308)));
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(ldr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec3 c = texelFetch(hdr, p, 0).rgb * pc.exposure;
    // NaN/Inf never reach the output silently: they show as magenta.
    if (any(isnan(c)) || any(isinf(c))) {
        imageStore(ldr, p, vec4(1, 0, 1, 1));
        return;
    }
    imageStore(ldr, p, vec4(srgb_oetf(aces(max(c, vec3(0.0)))), 1.0));
}
