#version 460
#extension GL_GOOGLE_include_directive : require
// mc-denoised, temporal accumulation (SVGF, Schied et al. 2017, section 4.1): this frame's mc
// samples, demodulated by the surface's reflectance, blended with the history found through the
// G-buffer's motion vector (the pixel the surface covered last frame) when that pixel showed the
// same instance at the same distance (else the history restarts: disocclusion), with weight
// 1 / (history length), the length capped at `max_history` (5 by default: SVGF's alpha = 0.2; a
// longer cap converges further on still views, a shorter one forgets moving shadows sooner: the
// floor under a falling object keeps its motion vector of zero while its shadow moves). Before
// the blend the history is clipped to this frame's 3x3 neighbourhood (`clip`, variance clipping
// as in temporal anti-aliasing; not SVGF's): lighting that changed without a motion vector
// leaves it. With the ratio estimator (mode.x) the unshadowed estimate of the same samples is
// accumulated and clipped alike, and the variance that guides the filter is the visible
// fraction's (S / U) as mc measured it from its own samples, averaged over the history like the
// radiance (a shadow that moves across a pixel does not count as noise, as the temporal moments
// of S / U would have it: god_rays 160x120 after five frames 0.108 -> 0.095), times 4 / length for
// a history shorter than 4 frames (SVGF's boost); without it the moments are the luminance's and
// a short history takes the 3x3 neighbourhood's spread instead where that is larger (SVGF's).
// With `restart` (mode.y) a history that this frame's visible fraction contradicts restarts
// (`history_contradicted`: a hard shadow moved over a floor whose motion vector is zero).
layout(local_size_x = 8, local_size_y = 8) in;
#include "common.glsl"
layout(binding = 0, rgba32f) uniform readonly image2D noisy;
layout(binding = 1) uniform sampler2D gb_position;
layout(binding = 2) uniform sampler2D gb_uv_mat;
layout(binding = 3) uniform sampler2D gb_motion;
// history: demodulated illumination and history length; luminance moments, distance to the eye,
// instance id + 1 (0: not covered)
layout(binding = 4, rgba32f) uniform readonly image2D prev_color;
layout(binding = 5, rgba32f) uniform readonly image2D prev_aux;
layout(binding = 6, rgba32f) uniform writeonly image2D new_color;
layout(binding = 7, rgba32f) uniform writeonly image2D new_aux;
// the filter's input: illumination and its luminance variance
layout(binding = 8, rgba32f) uniform writeonly image2D filter_in;
layout(std430, binding = 9) readonly buffer Materials { MaterialData mats[]; };
layout(binding = 10) uniform sampler2DArray material_textures;
// the ratio estimator (`ratio`, Heitz et al. 2018): this frame's unshadowed estimate from the
// same samples, its history (in and out) and its filter input, accumulated and clipped exactly
// as the shadowed radiance is; the history's alpha: mc's variance of the visible fraction
// averaged over the history; stand-ins left alone without it
layout(binding = 11, rgba32f) uniform readonly image2D noisy_u;
layout(binding = 12, rgba32f) uniform readonly image2D prev_u;
layout(binding = 13, rgba32f) uniform writeonly image2D new_u;
layout(binding = 14, rgba32f) uniform writeonly image2D filter_u;
#include "material.glsl"
#include "mc_denoise.glsl"

layout(push_constant) uniform Push {
    vec4 eye_valid;  // eye, w: 1 when the history images hold the previous frame
    uvec4 size;      // width, height, max history length, history clip (float bits; 0: off)
    uvec4 mode;      // x: 1 with the ratio estimator's unshadowed images; y: 1 restarts
                     // histories this frame's visible fraction contradicts
} pc;

// This frame's demodulated estimate at r: the shadowed (u = false) or the unshadowed one.
vec3 demodulated(ivec2 r, bool u) {
    vec3 c = u ? imageLoad(noisy_u, r).rgb : imageLoad(noisy, r).rgb;
    return c / mcd_reflectance(texelFetch(gb_uv_mat, r, 0));
}

// The history `hist` clipped to the 3x3 neighbourhood of this frame's estimate (`u`: the
// unshadowed one) around px, mean +- clip standard deviations per channel (Salvi 2016's variance
// clipping): what the lighting no longer shows (a shadow or highlight that moved without a motion
// vector) leaves the history.
vec3 clip_to_neighbourhood(ivec2 px, ivec2 size, vec3 hist, float clip, bool u) {
    vec3 s1 = vec3(0.0), s2 = vec3(0.0);
    float n = 0.0;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 r = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
            if (!(texelFetch(gb_position, r, 0).w > 0.0)) continue;
            vec3 ir = demodulated(r, u);
            s1 += ir;
            s2 += ir * ir;
            n += 1.0;
        }
    }
    // the pixel itself is covered: n >= 1
    vec3 mu = s1 / n, sigma = sqrt(max(s2 / n - mu * mu, vec3(0.0)));
    return clamp(hist, mu - clip * sigma, mu + clip * sigma);
}

// Whether the history's visible fraction r_hist (its variance averaged over the history: var)
// is out of this frame's at px, r: differing by more than half and by more than six standard
// deviations of the two, the variance of this frame's taken as the largest mc measured in the
// 3x3 neighbourhood (four samples that agreed by chance in a penumbra leave 0 at the pixel, rarely
// at all nine), and either the unshadowed estimate steady (`u_steady`: the lighting is the
// history's, only the visibility changed; a sample far out in U's tail moves U too) or at least
// two neighbours measuring about the same (a moved shadow is an area; a pixel whose samples all
// missed by chance is alone; but a one-pixel shadow beside its occluder, whose unlit side has no
// unshadowed light, has no such neighbours: god_rays at 40x30).
bool history_contradicted(ivec2 px, ivec2 size, float r, float r_hist, float var, bool u_steady) {
    float dr = abs(r - r_hist);
    if (!(dr > 0.5)) return false;
    float v = 0.0;
    int agree = 0;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
            vec4 u = imageLoad(noisy_u, q);
            v = max(v, u.a);
            float lu = mcd_luminance(u.rgb);
            // (the sky's "visible fraction" is 1: not a surface's)
            if ((dx != 0 || dy != 0) && lu > 0.0 && texelFetch(gb_position, q, 0).w > 0.0
                && abs(mcd_luminance(imageLoad(noisy, q).rgb) / lu - r) < 0.25) {
                agree += 1;
            }
        }
    }
    return dr > 6.0 * sqrt(v + var) && (agree >= 2 || u_steady);
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(pc.size.xy);
    if (any(greaterThanEqual(px, size))) return;
    vec4 pos = texelFetch(gb_position, px, 0);
    vec3 c = imageLoad(noisy, px).rgb;
    bool ratio = pc.mode.x != 0u;
    if (!(pos.w > 0.0)) {
        // Sky: mc's radiance is the environment's, without noise; nothing to keep.
        imageStore(new_color, px, vec4(0.0));
        imageStore(new_aux, px, vec4(0.0));
        imageStore(filter_in, px, vec4(c, 0.0));
        if (ratio) {
            imageStore(new_u, px, vec4(0.0));
            imageStore(filter_u, px, vec4(c, 0.0));
        }
        return;
    }
    vec4 uvm = texelFetch(gb_uv_mat, px, 0);
    vec3 illum = c / mcd_reflectance(uvm);
    vec3 illum_u = ratio ? imageLoad(noisy_u, px).rgb / mcd_reflectance(uvm) : vec3(0.0);
    vec3 hist_u = vec3(0.0);
    float hist_var = 0.0;
    // SVGF's luminance moments (with the ratio estimator mc's own variance guides the filter and
    // they go unused)
    float l = mcd_luminance(illum);
    float dist = length(pos.xyz - pc.eye_valid.xyz);
    float len = 0.0;
    vec3 hist = vec3(0.0);
    vec2 mom = vec2(0.0);
    if (pc.eye_valid.w > 0.5) {
        vec2 prev = vec2(px) + 0.5 - texelFetch(gb_motion, px, 0).xy;
        ivec2 q = ivec2(floor(prev));
        if (all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size))) {
            vec4 pa = imageLoad(prev_aux, q);
            if (abs(pa.w - uvm.w) < 0.5 && abs(pa.z - dist) < 0.05 * dist + 1e-4) {
                vec4 pcol = imageLoad(prev_color, q);
                len = pcol.a;
                hist = pcol.rgb;
                mom = pa.xy;
                if (ratio) {
                    vec4 pu = imageLoad(prev_u, q);
                    hist_u = pu.rgb;
                    hist_var = pu.a;
                }
            }
        }
    }
    if (ratio && pc.mode.y != 0u && len > 0.0) {
        // a shadow that moved over the pixel (the floor under a moving object keeps a motion
        // vector of zero: variance clipping keeps a hard edge's history, whose neighbourhood
        // spans lit and shadowed) restarts the history rather than dragging the old edge along
        float lu = mcd_luminance(illum_u), lhu = mcd_luminance(hist_u);
        // the unshadowed estimate steady: the lighting is the history's, only the visibility
        // changed (a sample far out in U's tail moves both S / U and U)
        bool u_steady = abs(lu - lhu) < 0.25 * max(lu, lhu);
        if (lu > 0.0 && lhu > 0.0
            && history_contradicted(px, size, mcd_luminance(illum) / lu, mcd_luminance(hist) / lhu, hist_var, u_steady)) {
            len = 0.0;
            hist_var = 0.0;
        }
    }
    float clip = uintBitsToFloat(pc.size.w);
    if (len > 0.0 && clip > 0.0) {
        hist = clip_to_neighbourhood(px, size, hist, clip, false);
        if (ratio) hist_u = clip_to_neighbourhood(px, size, hist_u, clip, true);
    }
    len = min(len + 1.0, float(max(pc.size.z, 1u)));
    float a = 1.0 / len;
    vec3 acc = mix(hist, illum, a);
    vec2 m = mix(mom, vec2(l, l * l), a);
    float var = max(m.y - m.x * m.x, 0.0);
    if (ratio) {
        vec3 acc_u = mix(hist_u, illum_u, a);
        // the visible fraction's variance from mc's own samples, averaged as the radiance is: a
        // hard shadow's edge, where every sample agrees, is not mistaken for noise as the
        // neighbourhood's spread would have it, nor a moving shadow as the moments would
        float avg_var = mix(hist_var, imageLoad(noisy_u, px).a, a);
        imageStore(new_u, px, vec4(acc_u, avg_var));
        imageStore(filter_u, px, vec4(acc_u, 0.0));
        var = avg_var * max(4.0 / len, 1.0);
    } else if (len < 4.0) {
        // SVGF's: the 3x3 neighbourhood's spread while the history is short
        float s1 = 0.0, s2 = 0.0, n = 0.0;
        for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
                ivec2 r = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
                if (!(texelFetch(gb_position, r, 0).w > 0.0)) continue;
                float lr = mcd_luminance(demodulated(r, false));
                s1 += lr;
                s2 += lr * lr;
                n += 1.0;
            }
        }
        if (n > 1.0) var = max(var, max(s2 / n - (s1 / n) * (s1 / n), 0.0) * 4.0 / len);
    }
    imageStore(new_color, px, vec4(acc, len));
    imageStore(new_aux, px, vec4(m, dist, uvm.w));
    imageStore(filter_in, px, vec4(acc, var));
}
