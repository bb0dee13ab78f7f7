#version 450
// Volumetric single scattering by ray marching (issue 7, eq. 1 of the temporal volumetric
// shadows thesis): in-scattered radiance along each view ray up to the G-buffer surface, with
// shadow-map visibility. Mode 1 (temporal) only recomputes pixels inside the mover mask and
// keeps the previous frame's value elsewhere (the history image is read and written in place).
#include "vol.glsl"
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Light { VolLight L; };
layout(set = 0, binding = 2) uniform sampler2D g_position;
layout(set = 0, binding = 3) uniform sampler2D shadow_map;
layout(set = 0, binding = 4) uniform sampler2D mask;
layout(set = 0, binding = 5, rgba32f) uniform image2D scatter;
layout(set = 0, binding = 6) uniform sampler2D intervals;  // hybrid: rgb front-most, a back-most

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(cam.params.xy);
    if (p.x >= size.x || p.y >= size.y) return;
    if (L.misc.x == 1u) {
        // The mask dilated by one pixel (shadow-map texels straddle the exact silhouettes).
        float m = 0.0;
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
                m = max(m, texelFetch(mask, clamp(p + ivec2(dx, dy), ivec2(0), size - 1), 0).r);
        if (m < 0.5) return;
    }
    vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec4 a = cam.inv_view_proj * vec4(ndc, 0.0, 1.0);
    vec4 b = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 o = cam.eye.xyz;
    vec3 d = normalize(b.xyz / b.w - a.xyz / a.w);
    vec4 gp = texelFetch(g_position, p, 0);
    float tmax = gp.w > 0.0 ? length(gp.xyz - o) : 1.0 / 0.0;
    // Fixed per-pixel offset (interleaved gradient noise): identical inputs give identical
    // results, so unchanged pixels can be reused bit for bit.
    float j = fract(52.9829189 * fract(0.06711056 * float(p.x) + 0.00583715 * float(p.y)));
    float t_front = 0.0, t_back = 1.0 / 0.0;
    if (L.extra.x > 0.5) {
        vec4 iv = texelFetch(intervals, p, 0);
        // No shadow-volume face on this pixel: the whole ray is lit. A camera in shadow starts
        // inside a volume: the shadowed interval then begins at the eye.
        bool eye_shadowed = L.misc.z != 0u && vol_visibility(L, shadow_map, o) < 0.5;
        t_front = eye_shadowed ? 0.0 : iv.r;
        t_back = iv.a > 0.0 ? iv.a : (eye_shadowed ? 1.0 / 0.0 : -1.0);
    }
    vec3 s = L.misc.z != 0u ? vol_inscatter(L, shadow_map, o, d, tmax, j, t_front, t_back) : vec3(0.0);
    s = max(s, vec3(0.0));
    if (any(isnan(s)) || any(isinf(s))) s = vec3(0.0);
    imageStore(scatter, p, vec4(s, float(L.misc.w)));
}
