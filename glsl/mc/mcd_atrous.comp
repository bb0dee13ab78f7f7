#version 460
#extension GL_GOOGLE_include_directive : require
// mc-denoised, one edge-aware a-trous wavelet iteration (SVGF, Schied et al. 2017, section 4.2;
// Dammertz et al. 2010): a 5x5 B3-spline kernel with taps `step` pixels apart, each tap
// weighted by the normals' agreement (pow(n . n_q, phi_normal)), the tap's distance from the
// pixel's tangent plane against `phi_plane` times the world size of `step` pixels there (the
// depth term), and the illumination's luminance difference (with the ratio estimator: the
// visible fraction's, mcd_edge_value) against phi_color times the standard deviation (3x3
// Gaussian of the variance) at the pixel; the variance is filtered with the
// squared weights. Taps on a face whose geometric normal is more than about 25 degrees from the
// pixel's are not mixed at all: the material model's face rule (light from below the face is
// blocked by it) makes the radiance jump there, and a coarse mesh's face turned from a light
// must stay black beside its lit neighbour (test light_below_the_face_lights_nothing_in_every_
// technique). The ratio estimator filters the unshadowed estimate with the same weights and the
// last iteration writes the analytic unshadowed radiance times the two's ratio; without it the
// last iteration multiplies the reflectance back. Uncovered pixels (sky) keep mc's radiance.
layout(local_size_x = 8, local_size_y = 8) in;
#include "common.glsl"
layout(binding = 0, rgba32f) uniform readonly image2D src;
layout(binding = 1, rgba32f) uniform writeonly image2D dst;
layout(binding = 2) uniform sampler2D gb_position;
layout(binding = 3) uniform sampler2D gb_normal;
layout(binding = 4) uniform sampler2D gb_uv_mat;
layout(binding = 5, rgba32f) uniform readonly image2D noisy;
layout(std430, binding = 6) readonly buffer Materials { MaterialData mats[]; };
layout(binding = 7) uniform sampler2DArray material_textures;
// the ratio estimator (`ratio`, Heitz et al. 2018): the unshadowed estimate, filtered with the
// same weights as the shadowed one, and the analytic unshadowed radiance (shade_env) that the
// last iteration multiplies by their ratio; stand-ins left alone without it
layout(binding = 8, rgba32f) uniform readonly image2D src_u;
layout(binding = 9, rgba32f) uniform writeonly image2D dst_u;
layout(binding = 10, rgba32f) uniform readonly image2D analytic;
#include "material.glsl"
#include "mc_denoise.glsl"

layout(push_constant) uniform Push {
    vec4 eye_pixel;  // eye, w: world size of one pixel at unit distance
    uvec4 step;      // tap spacing, width, height, 1 on the last iteration
    vec4 phi;        // phi_color, phi_normal, phi_plane, phi_lobe
    uvec4 mode;      // x: 1 with the ratio estimator
} pc;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(pc.step.yz);
    if (any(greaterThanEqual(px, size))) return;
    bool last = pc.step.w != 0u;
    vec4 pos = texelFetch(gb_position, px, 0);
    bool ratio = pc.mode.x != 0u;
    if (!(pos.w > 0.0)) {
        imageStore(dst, px, last ? vec4(imageLoad(noisy, px).rgb, 1.0) : imageLoad(src, px));
        if (ratio && !last) imageStore(dst_u, px, imageLoad(src_u, px));
        return;
    }
    vec4 cp = imageLoad(src, px);
    vec3 n = oct_decode(texelFetch(gb_normal, px, 0).xy);
    vec3 ng = gb_geometric_normal(pos.w);
    // 3x3 Gaussian of the variance: a steadier estimate of the pixel's noise.
    float gv = 0.0, gw = 0.0;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 r = px + ivec2(dx, dy);
            if (any(lessThan(r, ivec2(0))) || any(greaterThanEqual(r, size))) continue;
            if (!(texelFetch(gb_position, r, 0).w > 0.0)) continue;
            float w = (dx == 0 ? 2.0 : 1.0) * (dy == 0 ? 2.0 : 1.0);
            gv += w * imageLoad(src, r).a;
            gw += w;
        }
    }
    float sigma_l = pc.phi.x * sqrt(max(gv / max(gw, 1e-6), 0.0)) + 1e-6;
    float dist = length(pos.xyz - pc.eye_pixel.xyz);
    float plane_tol = max(pc.phi.z * dist * pc.eye_pixel.w * float(pc.step.x), 1e-6);
    float lp = mcd_edge_value(cp.rgb, ratio ? imageLoad(src_u, px).rgb : vec3(0.0), ratio);
    // Glossy pixels: a tap counts as much as its mirror direction falls inside this pixel's
    // specular lobe (sharpness ~ 1 / (2 r^2) about the reflection vector; Blinn-Phong s: s / 4),
    // scaled by the specular share of the reflectance and phi_lobe. A sharp highlight (the sun
    // in a shininess-1000 bunny: 20-115 against a mean of 1.4) then stays where it is instead of
    // being spread over the a-trous footprint; diffuse surfaces are filtered as before.
    vec3 eye = pc.eye_pixel.xyz;
    vec3 mirror = reflect(-normalize(eye - pos.xyz), n);
    MaterialData m = mcd_material(texelFetch(gb_uv_mat, px, 0));
    float ks = mcd_luminance(m.spec_rough.rgb) / max(mcd_luminance(m.spec_rough.rgb + m.albedo_kind.rgb), 1e-6);
    float rough = material_roughness(m);
    float lobe = material_kind(m) == 0 ? 0.0 : pc.phi.w * ks * 0.5 / max(rough * rough, 1e-4);
    const float h[3] = float[](0.375, 0.25, 0.0625);
    vec3 sum = vec3(0.0), sum_u = vec3(0.0);
    float wsum = 0.0, vsum = 0.0;
    int s = int(pc.step.x);
    for (int dy = -2; dy <= 2; ++dy) {
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 r = px + ivec2(dx, dy) * s;
            if (any(lessThan(r, ivec2(0))) || any(greaterThanEqual(r, size))) continue;
            vec4 rp = texelFetch(gb_position, r, 0);
            if (!(rp.w > 0.0) || dot(ng, gb_geometric_normal(rp.w)) < 0.9) continue;
            vec4 cq = imageLoad(src, r);
            vec3 uq = ratio ? imageLoad(src_u, r).rgb : vec3(0.0);
            vec3 nq = oct_decode(texelFetch(gb_normal, r, 0).xy);
            float w = h[abs(dx)] * h[abs(dy)];
            w *= pow(max(dot(n, nq), 0.0), pc.phi.y);
            w *= exp(-abs(dot(n, rp.xyz - pos.xyz)) / plane_tol);
            w *= exp(-abs(mcd_edge_value(cq.rgb, uq, ratio) - lp) / sigma_l);
            if (lobe > 0.0) {
                vec3 mq = reflect(-normalize(eye - rp.xyz), nq);
                w *= exp(lobe * (dot(mirror, mq) - 1.0));
            }
            sum += w * cq.rgb;
            sum_u += w * uq;
            wsum += w;
            vsum += w * w * cq.a;
        }
    }
    // The centre tap has weight h[0]^2 > 0, so wsum > 0.
    vec3 filtered = sum / wsum;
    float var = vsum / (wsum * wsum);
    if (last && ratio) {
        // shadowed over unshadowed, both filtered alike (their common noise cancels: 1 exactly
        // where no shadow ray was blocked), times the analytic unshadowed radiance; per channel,
        // at most 1 (a sample's shadowed estimate never exceeds its unshadowed one)
        vec3 fu = sum_u / wsum;
        vec3 a = imageLoad(analytic, px).rgb;
        vec3 r = vec3(0.0);
        float lu = mcd_luminance(fu);
        float rl = lu > 0.0 ? clamp(mcd_luminance(filtered) / lu, 0.0, 1.0) : 1.0;
        for (int c = 0; c < 3; ++c) r[c] = fu[c] > 1e-4 * lu ? clamp(filtered[c] / fu[c], 0.0, 1.0) : rl;
        imageStore(dst, px, vec4(a * r, 1.0));
    } else if (last) {
        imageStore(dst, px, vec4(filtered * mcd_reflectance_of(m), 1.0));
    } else {
        imageStore(dst, px, vec4(filtered, var));
        if (ratio) imageStore(dst_u, px, vec4(sum_u / wsum, 0.0));
    }
}
