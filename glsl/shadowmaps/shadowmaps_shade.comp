#version 460
#extension GL_GOOGLE_include_directive : require
// Shadow-map baseline ("shadowmaps"), shading per G-buffer pixel.
// Environment: K directional lights at stratified importance samples of it (weights L / (K pdf)),
// each with an orthographic depth map (layers 0..K of the depth array, rasterized by
// shadowmaps_depth.vert). `shading = lights` (the papers' baseline): the sum over k of
// BRDF x cos x lit fraction x weight. `shading = ratio` (default): a ratio estimator on the `env`
// technique's unshadowed lighting (env_shade.glsl), so glossy surfaces keep the environment's
// reflection (K delta lights alone render a glossy dish black): its diffuse part times the
// cosine- and weight-weighted lit fraction over the K directions, its glossy part times the
// lobe-weighted lit fraction, trusted as far as the directions hold the lobe's light; where they
// do not, the darker of the lit fraction under kernels around the mirror direction (as broad as
// the directions' spacing needs; then the diffuse one) and of pc.size.z rays around the mirror
// direction marched through the visual hull of the K maps.
// Local lights: point and spot lights with a cube shadow map each (6 layers after the K), 3x3 PCF;
// directional lights with one orthographic map each (as the K, 3x3 PCF);
// sphere lights from the cube map of their centre with PCSS soft shadows (blocker search, then a
// filter as wide as the penumbra a sphere of the light's radius casts); radiance with the material's
// BRDF, sphere lights as points of intensity L pi r^2.
// Lit fraction: 3x3 PCF (more for sphere lights), slope-scaled bias (the slope of the face: the
// G-buffer's geometric normal, not the interpolated one) of 1.5 texels + 1.5 texels x
// tan(theta), compared in linear depth.
layout(local_size_x = 8, local_size_y = 8) in;
#include "common.glsl"
layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
// per layer: view-projection (4 columns), (kind 0 ortho / 1 perspective, near, far, texel size)
layout(std430, set = 0, binding = 7) readonly buffer Layers { vec4 layers[]; };
// per environment light k: (direction towards the light, K pdf), (weight rgb, 0)
layout(std430, set = 0, binding = 8) readonly buffer EnvLights { vec4 env_lights[]; };
// the K environment layers (size pc.size.x), and the local lights' layers from K on (pc.size.y)
layout(set = 0, binding = 9) uniform sampler2DArray depth_maps;
layout(set = 0, binding = 10) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 11) uniform sampler2DArray material_textures;
layout(set = 0, binding = 12) uniform sampler2DArray light_depth_maps;
layout(push_constant) uniform Push {
    uvec4 counts;   // K environment layers, local light count, visibility on, shading (0 lights, 1 ratio)
    uvec4 size;     // the environment layers' resolution, the local lights' resolution, march rays, 0
} pc;

#define M_PI 3.14159265358979323846
#define M_TAU 6.28318530717958647692
#include "material.glsl"
#include "brdf_ref.glsl"
#include "env_shade.glsl"

// The glossy share's fallbacks (shading = ratio): von Mises-Fisher kernels exp(kappa (w.r - 1))
// around the mirror direction r, sharpest first, and the effective number of directions
// ((sum w)^2 / sum w^2) a kernel or the lobe must hold to be trusted fully.
#define SM_KERNELS 4
#define SM_NEFF 4.0
// The marched rays' offset from the mirror direction, in units of the lobe's GGX alpha
// (balls_on_dish 40x30, four rays: 1.0 0.083, 1.5 0.081, 2.0 0.085 rmse/mean; one ray along the
// mirror direction: 0.101, a hard-edged reflection of the balls).
#define SM_MARCH_SPREAD 1.5
float lum(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

// Texels per side of layer l: the environment's K layers, then the local lights'.
uint layer_size(uint l) { return l < pc.counts.x ? pc.size.x : pc.size.y; }

mat4 layer_vp(uint l) { return mat4(layers[5u * l], layers[5u * l + 1u], layers[5u * l + 2u], layers[5u * l + 3u]); }

// Linear depth (along the map's axis) of texel c of layer l; where nothing was drawn (the cleared
// 1.0) or, on an orthographic layer, outside the map (no shadow caster there: the maps cover the
// casters' bounding sphere), infinitely far.
float stored_depth(uint l, ivec2 c) {
    vec4 li = layers[5u * l + 4u];
    int s = int(layer_size(l));
    if (any(lessThan(c, ivec2(0))) || any(greaterThanEqual(c, ivec2(s)))) {
        if (li.x < 0.5) return 3.0e38;
        c = clamp(c, ivec2(0), ivec2(s - 1));
    }
    float d = l < pc.counts.x ? texelFetch(depth_maps, ivec3(c, int(l)), 0).r
                              : texelFetch(light_depth_maps, ivec3(c, int(l - pc.counts.x)), 0).r;
    if (d >= 1.0) return 3.0e38;
    return li.x < 0.5 ? li.y + d * (li.z - li.y) : li.y * li.z / (li.z - d * (li.z - li.y));
}

// Where p falls in layer l: texel coordinates (texel centres at integers), its linear depth and
// the world size of one texel there.
void project(uint l, vec3 p, out vec2 t, out float z, out float texel) {
    vec4 li = layers[5u * l + 4u];
    vec4 c = layer_vp(l) * vec4(p, 1.0);
    vec3 ndc = c.xyz / c.w;
    float s = float(layer_size(l));
    t = (ndc.xy * 0.5 + 0.5) * s - 0.5;
    z = li.x < 0.5 ? li.y + ndc.z * (li.z - li.y) : c.w;
    texel = li.x < 0.5 ? li.w : 2.0 * c.w / s;
}

float bias_for(float texel, float cos_i, float z) {
    float tan_i = sqrt(max(1.0 - cos_i * cos_i, 0.0)) / max(cos_i, 0.05);
    return texel * (1.5 + 1.5 * min(tan_i, 20.0)) + 1e-5 * z;
}

// 3x3 PCF lit fraction of p in layer l.
float lit_pcf(uint l, vec3 p, float cos_i) {
    vec2 t;
    float z, texel;
    project(l, p, t, z, texel);
    float zb = z - bias_for(texel, cos_i, z);
    ivec2 c0 = ivec2(round(t));
    float sum = 0.0;
    for (int dy = -1; dy <= 1; dy++) {
        for (int dx = -1; dx <= 1; dx++) {
            sum += zb <= stored_depth(l, c0 + ivec2(dx, dy)) ? 1.0 : 0.0;
        }
    }
    return sum / 9.0;
}

// PCSS lit fraction of p in layer l for a spherical light of radius `radius` at the map's
// centre of projection (perspective layers).
float lit_pcss(uint l, vec3 p, float cos_i, float radius) {
    vec2 t;
    float z, texel;
    project(l, p, t, z, texel);
    vec4 li = layers[5u * l + 4u];
    float zb = z - bias_for(texel, cos_i, z);
    // the widest search and filter: 16 texels of a 256-texel map, as many of this one's texels
    // as cover the same angle (the sample counts stay 5x5 and 7x7)
    float widest = 16.0 * max(float(layer_size(l)) / 256.0, 1.0);
    // blockers between the light and p within the light's angular size as seen from p, mapped
    // into the map (texels at p's depth), searched over a 5x5 grid
    float search = clamp(radius / max(texel, 1e-9), 1.0, widest);
    float blockers = 0.0, zsum = 0.0;
    for (int dy = -2; dy <= 2; dy++) {
        for (int dx = -2; dx <= 2; dx++) {
            vec2 q = t + vec2(dx, dy) * (search / 2.0);
            float d = stored_depth(l, ivec2(round(q)));
            if (d < zb) {
                blockers += 1.0;
                zsum += d;
            }
        }
    }
    if (blockers == 0.0) return 1.0;
    float zblock = max(zsum / blockers, li.y);
    // penumbra width at p (world), in texels at p's depth
    float penumbra = radius * (z - zblock) / zblock;
    float filt = clamp(penumbra / max(texel, 1e-9), 1.0, widest);
    float sum = 0.0;
    for (int dy = -3; dy <= 3; dy++) {
        for (int dx = -3; dx <= 3; dx++) {
            vec2 q = t + vec2(dx, dy) * (filt / 3.0);
            sum += zb <= stored_depth(l, ivec2(round(q))) ? 1.0 : 0.0;
        }
    }
    return sum / 49.0;
}

// Whether the ray p + s dir (s0 <= s <= len) passes through the visual hull of the K
// environment maps: blocked where a point of it lies behind the stored depth in every map. A
// closed occluder's inside is behind its front surface from every direction, so the hull holds
// every occluder, and the K directions spread over the sphere keep it tight around them: it stands
// in for the occluders along the directions no map looks along. (Thin open surfaces seen from
// both sides are missed.) The maps are tried from `first` on, the first one that sees the point
// in front of its depth ending the test.
#define SM_MARCH_STEPS 32
float march_maps(vec3 p, vec3 dir, float s0, float len, uint first) {
    uint kc = pc.counts.x;
    for (int i = 0; i < SM_MARCH_STEPS; i++) {
        float f = (float(i) + 0.5) / float(SM_MARCH_STEPS);
        vec3 x = p + dir * (s0 + (len - s0) * f * f);
        bool inside = true;
        for (uint j = 0u; j < kc && inside; j++) {
            uint l = (first + j) % kc;
            vec2 t;
            float z, texel;
            project(l, x, t, z, texel);
            inside = z - 1.5 * texel > stored_depth(l, ivec2(round(t)));
        }
        if (inside) return 0.0;
    }
    return 1.0;
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (px.x >= size.x || px.y >= size.y) return;
    vec4 uvm = texelFetch(gb_uv_mat, px, 0);
    vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 d = normalize(far_p.xyz / far_p.w - cam.eye.xyz);
    if (uvm.w < 0.5) {
        imageStore(hdr, px, vec4(env_background(d), 1.0));
        return;
    }
    vec4 gp = texelFetch(gb_position, px, 0);
    vec3 p = gp.xyz, ng = gb_geometric_normal(gp.w);
    vec4 en = texelFetch(gb_normal, px, 0);
    vec3 ns = oct_decode(en.xy);
    vec3 tg = oct_decode(en.zw);
    vec3 wo_w = normalize(cam.eye.xyz - p);
    // (two-sided: the G-buffer's normal is on the eye's side of its triangle and turned towards
    // the eye where a normal map or an interpolated normal at a silhouette turned it away:
    // material_facing_normal; material_reflected below only guards)
    mat3 frame = brdf_frame(ns, tg);
    vec3 wo = wo_w * frame;
    uint mi = uint(uvm.z + 0.5);
    MaterialData m = material_at(mats[mi], uvm.xy, material_textures);
    Brdf b = brdf_from_material(m);
    bool vis_on = pc.counts.z != 0u;
    // environment
    vec3 s_vis = vec3(0.0), s_all = vec3(0.0);   // shading = lights: BRDF x cos x weight
    vec3 d_vis = vec3(0.0), d_all = vec3(0.0);   // ratio, diffuse: cos x weight
    float g_vis = 0.0, g_all = 0.0;              // ratio, glossy: the BRDF's glossy lobe x cos
    float g_light = 0.0;                         // the lobe's unshadowed light, estimated from them
    Brdf glossy_b = b;
    glossy_b.albedo = vec3(0.0);
    float g_sq = 0.0;                            // sum of the lobe's weights squared
    // ratio, glossy fallbacks: per kernel around the mirror direction, sum w V, sum w, sum w^2
    // (w = kernel x cos) and sum kernel / (K pdf) over all K (its integral's estimate)
    vec3 refl = reflect(-wo_w, ns);
    const float KAPPA[SM_KERNELS] = float[SM_KERNELS](128.0, 32.0, 8.0, 2.0);
    float kv[SM_KERNELS], ka[SM_KERNELS], kq[SM_KERNELS], kc[SM_KERNELS];
    for (int j = 0; j < SM_KERNELS; j++) { kv[j] = 0.0; ka[j] = 0.0; kq[j] = 0.0; kc[j] = 0.0; }
    bool kernels = pc.counts.w != 0u && b.kind != 0u;
    // the environment layer whose direction is nearest the mirror direction (the march's first)
    uint near0 = 0xffffffffu;
    float c0 = -2.0;
    for (uint k = 0u; k < pc.counts.x; k++) {
        vec3 wi = env_lights[2u * k].xyz;
        vec3 lw = wi * frame;
        float kpdf = env_lights[2u * k].w;
        float cr = dot(wi, refl);
        float kern[SM_KERNELS];  // each kernel's value at wi
        for (int j = 0; j < SM_KERNELS; j++) kern[j] = kernels ? exp(KAPPA[j] * (cr - 1.0)) : 0.0;
        if (kernels && kpdf > 0.0) {
            for (int j = 0; j < SM_KERNELS; j++) kc[j] += kern[j] / kpdf;
            if (cr > c0) { near0 = k; c0 = cr; }
        }
        if (lw.z <= 0.0 || wo.z <= 0.0) continue;
        vec3 w = env_lights[2u * k + 1u].rgb;
        // below the geometric surface: blocked by it (lights.glsl's rule)
        float v = dot(wi, ng) <= 0.0 ? 0.0 : (vis_on ? lit_pcf(k, p, dot(wi, ng)) : 1.0);
        if (pc.counts.w == 0u) {
            vec3 f = brdf_eval(b, wo, lw) * lw.z * w;
            s_all += f;
            s_vis += f * v;
        } else {
            d_all += lw.z * w;
            d_vis += lw.z * w * v;
            if (kernels) {
                for (int j = 0; j < SM_KERNELS; j++) {
                    float kw = kern[j] * lw.z;
                    ka[j] += kw;
                    kq[j] += kw * kw;
                    kv[j] += kw * v;
                }
                float g = lum(brdf_eval(glossy_b, wo, lw)) * lw.z;
                g_all += g;
                g_sq += g * g;
                g_vis += g * v;
                g_light += g * lum(w);
            }
        }
    }
    vec3 l;
    if (pc.counts.w == 0u) {
        l = s_vis;
    } else {
        // Ratio estimators. The diffuse share is the cosine- and weight-weighted mean visibility
        // over the K directions. The K directions are importance samples of the environment (each
        // weight L / (K pdf) about equal), so the glossy share is the lobe-weighted mean
        // visibility over them, sum f V / sum f, where they cover the lobe (below). No direction
        // above the horizon: unshadowed.
        vec3 ud, ug;
        env_unshadowed_parts(ns, tg, wo_w, m, ud, ug);
        vec3 rd = vec3(
            d_all.r > 0.0 ? d_vis.r / d_all.r : 1.0,
            d_all.g > 0.0 ? d_vis.g / d_all.g : 1.0,
            d_all.b > 0.0 ? d_vis.b / d_all.b : 1.0);
        float rd_lum = lum(d_all) > 0.0 ? lum(d_vis) / lum(d_all) : 1.0;
        // The glossy share, from the broadest estimate to the sharpest. The diffuse share; then
        // each kernel around the mirror direction (the lobe-weighted visibility blurred to the
        // directions' spacing), trusted as far as the directions cover it (the estimate of its
        // integral, sum w / (K pdf), against the exact one) and hold SM_NEFF of them (effective
        // count (sum w)^2 / sum w^2); then, darker of the two, rays around the mirror direction
        // through the maps' visual hull (march_maps: occluders along directions no map looks
        // along, such as the balls a glossy dish reflects); then the lobe's own lit fraction over
        // the K directions, trusted as far as they hold the lobe's unshadowed light (their
        // estimate of it, sum f cos L / (K pdf), against the prefiltered one: a lobe holding the
        // sun's directions is trusted whatever its tails) and SM_NEFF of them (one direction in
        // the lobe, or a few in its tail only, is not its visibility). Measured in session 45.
        float rg = rd_lum;
        if (kernels) {
            for (int j = SM_KERNELS - 1; j >= 0; j--) {
                if (!(ka[j] > 1e-30)) continue;
                float integral = M_TAU / KAPPA[j] * (1.0 - exp(-2.0 * KAPPA[j]));
                float trust = clamp(kc[j] / integral, 0.0, 1.0) * clamp((ka[j] * ka[j] / kq[j] - 1.0) / (SM_NEFF - 1.0), 0.0, 1.0);
                rg = mix(rg, kv[j] / ka[j], trust);
            }
        }
        float lobe_trust = 0.0, lobe_vis = 1.0;
        if (kernels && g_all > 1e-30) {
            float cover = lum(ug) > 0.0 ? clamp(g_light / lum(ug), 0.0, 1.0) : 0.0;
            float held = clamp((g_all * g_all / max(g_sq, 1e-30) - 1.0) / (SM_NEFF - 1.0), 0.0, 1.0);
            lobe_trust = cover * held;
            lobe_vis = g_vis / g_all;
        }
        uint rays = min(pc.size.z, 16u);
        if (kernels && vis_on && rays > 0u && near0 != 0xffffffffu && lobe_trust < 1.0) {
            // from three texels off the surface (along its normal) to the far side of the
            // casters' bounding sphere (the layers' depth range); a ray below the face is blocked
            vec4 li = layers[5u * near0 + 4u];
            float s0 = 3.0 * li.w / max(dot(refl, ng), 0.1);
            float spread = SM_MARCH_SPREAD * env_alpha(m);
            vec3 ta = normalize(abs(refl.y) < 0.9 ? cross(refl, vec3(0.0, 1.0, 0.0)) : cross(refl, vec3(1.0, 0.0, 0.0)));
            vec3 tb = cross(refl, ta);
            float mv = 0.0;
            for (uint q = 0u; q < rays; q++) {
                float ang = (float(q) + 0.5) * (M_TAU / float(rays));
                vec3 dq = rays == 1u ? refl : normalize(refl + spread * (cos(ang) * ta + sin(ang) * tb));
                mv += dot(dq, ng) <= 0.0 ? 0.0 : march_maps(p, dq, s0, max(li.z, s0), near0);
            }
            rg = min(rg, mv / float(rays));
        }
        rg = mix(rg, lobe_vis, lobe_trust);
        l = ud * rd + ug * rg;
    }
    // local lights: 6 cube layers each after the K, one orthographic layer for a directional one
    uint next_layer = pc.counts.x;
    for (uint i = 0u; i < pc.counts.y; i++) {
        LightData ld = lights[i];
        int lk = int(ld.pos_kind.w + 0.5);
        uint first_layer = next_layer;
        next_layer += lk == 3 ? 1u : 6u;
        if (lk == 3) {
            // directional: irradiance `power` along its direction, lit fraction from its map
            vec3 wi = -ld.dir_cos_outer.xyz;
            vec3 lw = wi * frame;
            if (lw.z <= 0.0 || wo.z <= 0.0 || dot(wi, ng) <= 0.0) continue;
            vec3 f = brdf_eval(b, wo, lw) * lw.z;
            l += f * ld.power_cos_inner.rgb * (vis_on ? lit_pcf(first_layer, p, dot(wi, ng)) : 1.0);
            continue;
        }
        vec3 to_l = ld.pos_kind.xyz - p;
        float d2 = dot(to_l, to_l);
        if (d2 <= 1e-12) continue;
        vec3 wi = to_l * inversesqrt(d2);
        vec3 lw = wi * frame;
        if (lw.z <= 0.0 || wo.z <= 0.0 || dot(wi, ng) <= 0.0) continue;
        vec3 intensity = ld.power_cos_inner.rgb;
        float radius = ld.extra.x;
        if (lk == 1) {
            intensity *= smoothstep(ld.dir_cos_outer.w, ld.power_cos_inner.w, dot(-wi, normalize(ld.dir_cos_outer.xyz)));
        } else if (lk == 2) {
            if (d2 <= radius * radius) continue;
            intensity *= M_PI * radius * radius;
        }
        intensity *= light_transmittance(ld, sqrt(d2));
        if (intensity == vec3(0.0)) continue;
        vec3 f = brdf_eval(b, wo, lw) * lw.z;
        if (f == vec3(0.0)) continue;
        float v = 1.0;
        if (vis_on) {
            // the cube face of -wi (the direction from the light to p)
            vec3 a = abs(wi);
            uint face = a.x >= a.y && a.x >= a.z ? (-wi.x >= 0.0 ? 0u : 1u)
                      : (a.y >= a.z ? (-wi.y >= 0.0 ? 2u : 3u) : (-wi.z >= 0.0 ? 4u : 5u));
            uint layer = first_layer + face;
            v = lk == 2 ? lit_pcss(layer, p, dot(wi, ng), radius) : lit_pcf(layer, p, dot(wi, ng));
        }
        l += f * intensity / d2 * v;
    }
    imageStore(hdr, px, vec4(material_reflected(l, ns, wo_w) + material_emission(m), 1.0));
}
