#version 460
#extension GL_GOOGLE_include_directive : require
// AVS shading (Wang et al., section 6): per pixel, the sample points within the search radius
// (uniform grid built on the CPU) with the best eq. 8 weights (inverse e_g); their fp16 SSDFs
// (bilinear, corrected by half a texel so that zero lies on the boundary between texel centres)
// are interpolated at any world direction; lighting = K SG lobes of the environment, BRDF = one
// SG lobe (Blinn-Phong / Cook-Torrance warps as isg_shade.comp), cosine as an SG. The visibility
// of each product lobe over the visible region:
//   mode 0 (lobe axis, Wang et al. 2009): the signed distance d at the lobe axis, a straight
//           boundary at distance d: visible fraction Phi(d sqrt(lambda)) (normal CDF);
//   mode 1 (cells): the lobe's neighbourhood (+-3 / sqrt(lambda), clamped to the hemisphere) in
//           C x C cells of its tangent plane; in each cell the boundary is the iso-line of the
//           bilinear SSDF through the corners (visible fraction from 2 x 2 sub-cells), and the
//           lobe is integrated over the visible part of every cell (eq. 5, numerically per cell);
//   mode 2 (table, part A): T(lambda, d) of include/ssdf_integrate.glsl (tabulated integral of
//           the lobe over the region beyond a cap boundary at signed distance d of the axis)
//           instead of the straight-edge Phi;
//   mode 3 (adaptive cells, part A): ssdf_visible_cells of include/ssdf_integrate.glsl (distance-
//           field quadtree, iso-line clipped boundary texels, eq. 5) over a virtual map in the
//           pixel's frame whose texels are the interpolated SSDF; ~1 ms per pixel on lavapipe:
//           only for tiny images. Wrong on lavapipe: a pixel needs more than the driver's 65535
//           loop iterations per invocation, after which every loop stops early (see
//           Integration::Adf).
// Diffuse (diffuse_ratio, default): the map's exact irradiance times the visible share of the
// lobes' irradiance (include/irradiance.glsl), not the lobes alone (the paper's; its fit error).
// Glossy (glossy ratio, default): the material model's glossy term (env_shade.glsl, the `env`
// technique's) times the specular lobe's light-weighted SSDF visibility (main's glossy items: the
// lighting lobes' and key lights' visible shares weighted by their light in the lobe), not the
// one SG lobe of the BRDF.
// Key lights (key_lights, with light_shadows = traced): the environment's sun or studio lights
// split off the map (every SG lobe, the irradiance and the prefiltered maps are the rest's),
// their diffuse light shadowed by 9 rays each through the kd-tree (light_rays.glsl, the inner ring
// only in a penumbra), the same rays weighted by the glossy lobe for their glossy light where the
// lobe is nearly flat over the light (KEY_REUSE); a sharper lobe takes rays of its own in the
// cone of its product with the light.
// Local lights (light_shadows): shadow rays traced through the frame's kd-tree (default; the paper
// lights by the environment only, and a point or spot light's hard shadow is finer than maps
// interpolated between sample points), or the sign of the interpolated SSDF toward the light.
#include "common.glsl"
#include "sg.glsl"
#include "avs_maps.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
layout(set = 0, binding = 7) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 8) uniform sampler2DArray material_textures;
#include "material.glsl"
#include "lights.glsl"
#include "env_shade.glsl"
layout(set = 0, binding = 9) readonly buffer Lobes { vec4 lobes[]; };
layout(set = 0, binding = 10) readonly buffer Prefiltered { float pf[]; };
// Bindings 11-14 are texel buffers (R32G32B32A32_UINT views: one gather per 16-byte texel on a
// CPU device, where a storage-buffer read at a per-pixel index is a scalar load per lane and
// component).
// 3 texels per slot: (position, offset), (tangent, active), (normal, 0) as float bits
layout(set = 0, binding = 11) uniform usamplerBuffer pts_t;
// uniform grid, four words to a texel: [0..2] dims, [3] unused, [4..6] lower corner (float bits),
// [7] cell edge (float bits), [8] first item word; cell_start at 16 (cells + 1 entries, relative
// to the first item word), then slots
layout(set = 0, binding = 12) uniform usamplerBuffer grid_t;
// the SSDFs (avs_maps.glsl: two fp16 texels to a word), four words to a texel
layout(set = 0, binding = 13) uniform usamplerBuffer ssdf_t;
// T(lambda, d), [SSDF_N_LAMBDA][SSDF_N_W] (penumbra_math::ssdf_integrate::AxisTable), mode 2;
// four floats to a texel
layout(set = 0, binding = 14) uniform usamplerBuffer axis_table_t;
#define AVS_PTS(i) uintBitsToFloat(texelFetch(pts_t, int(i)))
#define AVS_GRID(i) (texelFetch(grid_t, int(i) >> 2)[int(i) & 3])
// the SSDF value of texel k of the map at word `base`
float ssdf_at_word(uint base, uint k) {
    uint wi = base + (k >> 1u);
    vec2 h = unpackHalf2x16(texelFetch(ssdf_t, int(wi >> 2u))[wi & 3u]);
    return (k & 1u) == 0u ? h.x : h.y;
}
// the environment's irradiance map (passes::lighting::irradiance_env): the ratio estimator's
// unshadowed diffuse term
layout(set = 0, binding = 15) readonly buffer Irradiance { float irr[]; };
// the frame's kd-tree (include/kdtree.glsl): local lights' shadow rays (flags bit 1)
layout(set = 0, binding = 16) uniform usamplerBuffer kd_tris;
layout(set = 0, binding = 17) uniform usamplerBuffer kd_nodes;
layout(set = 0, binding = 18) uniform usamplerBuffer kd_refs;
layout(set = 0, binding = 19) readonly buffer Header { uint kd_hdr[]; };
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"
// the environment's key lights split off its map (AvsSettings::key_lights), 2 per light: world
// axis + lambda, rgb amplitude; their diffuse light is shadowed by rays through the kd-tree
layout(set = 0, binding = 20) readonly buffer KeyLights { vec4 key[]; };
// key_filter (flags bit 5): the key lights' diffuse light apart, for avs_key_filter.comp: rgb
// the unshadowed radiance it would add (after material_reflected), a its visible share (the
// lights' kfrac weighted by their luminance); `hdr` then holds the rest. Else a 1 x 1 stand-in.
layout(set = 0, binding = 21, rgba32f) uniform writeonly image2D key_out;
// ... and where its occluders are: x the mean distance to them along the blocked rays (0 where
// none was hit), y the lights' angular radius (tangent), both weighted by the lights' luminance
layout(set = 0, binding = 22, rgba32f) uniform writeonly image2D key_aux;
layout(push_constant) uniform Push {
    uint light_count;
    uint lobe_count;
    uint r;
    uint max_neighbours;
    float alpha;
    float inv_scale;
    float radius;
    uint flags;      // bit 0: no SSDF visibility (shadows off, or no sample points); bit 1: local lights' and key lights' shadows traced; bit 2: key_rays = predicted; bit 3: key_pattern = stratified; bit 4: key_penumbra = refine; bit 5: key_filter (the key lights' diffuse light written apart, key_out and key_aux)
    uint cells;      // cells per side (mode 1)
    uint specular_mode;  // 0: Gamma_L from the prefiltered maps, 1: from the lighting SGs, 2: ratio (env_shade.glsl's glossy term x the lobe's SSDF visibility)
    uint diffuse_ratio;  // 1: the map's irradiance x the SG lobes' visible share; 0: the SG lobes alone
    float ray_offset;    // shadow rays start this far along the normal, and skip hits nearer than it (the sample points' offset, avs::ray_offset)
    uint key_count;      // key lights split off the environment (binding 20)
} pc;
// key_pattern = stratified (flags bit 3): light_rays.glsl's per-pixel stratified key-light rays
#define CONE_STRATIFIED ((pc.flags & 8u) != 0u)
#include "light_rays.glsl"

#include "avs_gather.glsl"
#include "irradiance.glsl"

bool shadows_on() { return (pc.flags & 1u) == 0u && nb_count > 0u; }

// Corrected SSDF value of texel k of the map at slot.
float ssdf_texel(uint base, uint k) {
    float d = ssdf_at_word(base, k);
    float h = avs_texel_angle(pc.r);
    return abs(d) >= 3.0 ? d : d - sign(d) * 0.5 * h;
}

// Bilinear SSDF of one sample point at a world direction. Directions below the point's horizon
// (its normal differs from the pixel's) take the value at the horizon above them.
float ssdf_point(uint q, vec3 w, bool corrected) {
    vec3 l = transpose(nb_frame[q]) * w;
    float below = 0.0;
    if (l.z < 0.0) {
        l.z = 0.0;
        float len = length(l.xy);
        l = len > 1e-6 ? vec3(l.xy / len, 0.0) : vec3(1.0, 0.0, 0.0);
    }
    vec2 tp = avs_local_to_angles(l) * (float(pc.r) / float(AVS_PI)) - 0.5;
    tp = clamp(tp, vec2(0.0), vec2(float(pc.r) - 1.0));
    uvec2 i0 = uvec2(tp);
    uvec2 i1 = min(i0 + 1u, uvec2(pc.r - 1u));
    vec2 f = tp - vec2(i0);
    uint base = nb_slot[q] * avs_ssdf_words_per_map(pc.r);
    uvec4 k = uvec4(i0.x * pc.r + i0.y, i0.x * pc.r + i1.y, i1.x * pc.r + i0.y, i1.x * pc.r + i1.y);
    float a = corrected ? ssdf_texel(base, k.x) : ssdf_at_word(base, k.x);
    float b = corrected ? ssdf_texel(base, k.y) : ssdf_at_word(base, k.y);
    float c = corrected ? ssdf_texel(base, k.z) : ssdf_at_word(base, k.z);
    float d = corrected ? ssdf_texel(base, k.w) : ssdf_at_word(base, k.w);
    return mix(mix(a, b, f.y), mix(c, d, f.y), f.x) - below;
}

// Eq. 8 interpolation of the neighbours' SSDFs at world direction w.
float ssdf_at(vec3 w) {
    float s = 0.0;
    for (uint q = 0u; q < nb_count; ++q) s += nb_w[q] * ssdf_point(q, w, true);
    return s;
}

// Mode 3: texel k of a virtual map in the pixel's frame = the interpolated SSDF (uncorrected:
// ssdf_integrate.glsl applies its own half-texel correction).
mat3 pix_frame = mat3(1.0);
float ssdf_virtual(uint k) {
    vec3 w = pix_frame * avs_texel_dir(k / pc.r, k % pc.r, pc.r);
    float s = 0.0;
    for (uint q = 0u; q < nb_count; ++q) s += nb_w[q] * ssdf_point(q, w, false);
    return s;
}
#define SSDF_FETCH(k) ssdf_virtual(k)
#define SSDF_TABLE(i) uintBitsToFloat(texelFetch(axis_table_t, int(i) >> 2)[int(i) & 3])
#include "ssdf_integrate.glsl"

// The integration mode, a specialization constant (0 lobe axis, 1 cells, 2 table, 3 adaptive
// cells): the pipeline holds one mode's code (lavapipe compiles all of a pipeline's code at its
// first dispatch).
layout(constant_id = 0) const uint AVS_MODE = 0u;

float phi_cdf(float x) { return 0.5 * (1.0 + sg_erf(x * 0.70710678)); }

// A key light's unoccluded share from its rays' mask (cone_rays_mask: the disk's 9 rays, the
// same pattern in every pixel). In a penumbra (the rays disagree) with key_penumbra = refine
// (flags bit 4; the default `rays` keeps the 9 rays' share), 16 more rays, one in each of 16
// equal-area cells of the disk (4 rings of 4 sectors) at a point drawn per shading point, and
// the share of all of them: the fixed pattern's 9 flat steps (each ray a shifted copy of the
// occluder's hard shadow, streaks under a wide light) become 25 finer ones with a little grain.
float key_penumbra_fraction(uint m, vec3 p, vec3 axis, float radius, vec3 ng) {
    float vis = float(bitCount(m & 0xFFFFu)), cnt = float(bitCount(m >> 16u));
    if ((pc.flags & 16u) == 0u || cnt == 0.0 || vis == 0.0 || vis == cnt) return cnt > 0.0 ? vis / cnt : 1.0;
    vec3 w = normalize(axis);
    for (uint j = 0u; j < 16u; ++j) {
        uint h = cone_hash(p, j + 1u);
        float u = float(h & 0xFFFFu) / 65536.0, v = float(h >> 16u) / 65536.0;
        float a = 1.5707963 * (float(j & 3u) + u);
        float r = radius * sqrt((float(j >> 2u) + v) / 4.0);
        vec3 d = normalize(w + light_disk_offset(w, a) * r);
        if (dot(d, ng) <= 0.0) continue;
        cnt += 1.0;
        if (kd_trace(p, d, 0.0, 1e30, true).t < 0.0) vis += 1.0;
    }
    return vis / cnt;
}

// Visible fraction of SG lobe g (its mass) over the interpolated visible region.
float visible(SG g) {
    if (!shadows_on()) return 1.0;
    float lam = max(g.lambda, 1e-3);
    if (AVS_MODE == 0u) return phi_cdf(ssdf_at(g.axis) * sqrt(lam));
    if (AVS_MODE == 2u) return ssdf_table_lookup(lam, ssdf_at(g.axis));
    if (AVS_MODE == 3u) {
        vec3 la = transpose(pix_frame) * normalize(g.axis);
        float hemi = sg_hemisphere_integral(sg_make(la, lam, 1.0), vec3(0.0, 0.0, 1.0));
        return hemi > 1e-20 ? clamp(ssdf_visible_cells(la, lam, 1.0, false, pc.r) / hemi, 0.0, 1.0) : 1.0;
    }
    // mode 1: cells of the lobe's tangent plane, extent +-3 sigma (at most 1.5 rad)
    uint c = clamp(pc.cells, 1u, 16u);
    float ext = min(3.0 / sqrt(lam), 1.5);
    vec3 a = normalize(g.axis);
    vec3 up = abs(a.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 tx = normalize(cross(up, a)), ty = cross(a, tx);
    float dcorner[17 * 17];
    for (uint y = 0u; y <= c; ++y) {
        for (uint x = 0u; x <= c; ++x) {
            vec2 uv = (vec2(x, y) / float(c) * 2.0 - 1.0) * ext;
            dcorner[y * 17u + x] = ssdf_at(normalize(a + tx * tan(uv.x) + ty * tan(uv.y)));
        }
    }
    float vis = 0.0, tot = 0.0;
    for (uint y = 0u; y < c; ++y) {
        for (uint x = 0u; x < c; ++x) {
            float d00 = dcorner[y * 17u + x], d10 = dcorner[y * 17u + x + 1u];
            float d01 = dcorner[(y + 1u) * 17u + x], d11 = dcorner[(y + 1u) * 17u + x + 1u];
            // SG mass of the cell (weight at the centre times the cell's extent)
            vec2 uv = ((vec2(x, y) + 0.5) / float(c) * 2.0 - 1.0) * ext;
            float wgt = exp(-lam * (uv.x * uv.x + uv.y * uv.y) * 0.5);
            float frac;
            if (min(min(d00, d10), min(d01, d11)) >= 0.0) frac = 1.0;
            else if (max(max(d00, d10), max(d01, d11)) <= 0.0) frac = 0.0;
            else {
                // iso-line of the bilinear field: visible share of 4 x 4 sub-cells
                frac = 0.0;
                for (int sy = 0; sy < 4; ++sy)
                    for (int sx = 0; sx < 4; ++sx) {
                        vec2 f = (vec2(sx, sy) + 0.5) / 4.0;
                        float d = mix(mix(d00, d10, f.x), mix(d01, d11, f.x), f.y);
                        frac += d > 0.0 ? 1.0 / 16.0 : 0.0;
                    }
            }
            vis += wgt * frac;
            tot += wgt;
        }
    }
    return tot > 0.0 ? vis / tot : 1.0;
}

// Unoccluded fraction of local light l seen from o (the offset shading point): one shadow ray
// for point, spot and directional lights, lights.glsl's disk targets for a sphere light.
float traced_light_visibility(vec3 o, LightData l, int lk) {
    vec3 to_light = light_vector(l, o);
    int n = lk == 2 ? LIGHT_DISK_POINTS : 1;
    float vis = 0.0, cnt = 0.0;
    for (int i = 0; i < n; ++i) {
        if (disk_settled(i, vis, cnt)) break;
        cnt += 1.0;
        vec3 q = light_disk_target(to_light, lk == 2 ? l.extra.x : 0.0, disk_ray(i));
        float len = length(q);
        if (!(len > 0.0)) { vis += 1.0; continue; }
        vis += kd_trace(o, q / len, pc.ray_offset, len * (1.0 - 1e-4), true).t < 0.0 ? 1.0 : 0.0;
    }
    return vis / cnt;
}

vec3 local_lights(vec3 pos, vec3 n, vec3 t, vec3 ng, vec3 v, vec3 albedo, MaterialData m) {
    vec3 sum = vec3(0.0);
    bool traced = (pc.flags & 2u) != 0u;
    vec3 o = pos + n * pc.ray_offset;
    for (uint i = 0u; i < pc.light_count; ++i) {
        LightData l = lights[i];
        vec3 wi;
        float dist, ndl;
        vec3 e = light_incident(l, pos, n, ng, wi, dist, ndl);
        if (ndl <= 0.0) continue;
        vec3 f = light_brdf(wi, n, t, v, albedo, m);
        int lk = int(l.pos_kind.w + 0.5);
        float vis = 1.0;
        if (traced) {
            vis = traced_light_visibility(o, l, lk);
        } else if (shadows_on()) {
            // the interpolated SSDF toward the light (soft over one texel, or over the sphere
            // light's angular radius)
            float ang = lk == 2 ? asin(clamp(l.extra.x / dist, 0.0, 1.0)) : 0.0;
            vis = clamp(0.5 + ssdf_at(wi) / max(2.0 * ang, avs_texel_angle(pc.r)), 0.0, 1.0);
        }
        sum += f * e * ndl * vis;
    }
    return sum;
}

#include "env_background.glsl"

#include "prefiltered.glsl"


void gather_neighbours(vec3 pos, vec3 n) {
    avs_gather(pos, n, pc.radius, pc.alpha, pc.inv_scale, pc.max_neighbours);
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (px.x >= size.x || px.y >= size.y) return;
    vec4 uvm = texelFetch(gb_uv_mat, px, 0);
    if (uvm.w < 0.5) {
        vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
        imageStore(hdr, px, vec4(env_background(far_p.xyz / far_p.w - cam.eye.xyz), 1.0));
        if ((pc.flags & 32u) != 0u) {
            imageStore(key_out, px, vec4(0.0, 0.0, 0.0, 1.0));
            imageStore(key_aux, px, vec4(0.0));
        }
        return;
    }
    vec4 gp = texelFetch(gb_position, px, 0);
    vec3 pos = gp.xyz, ng = gb_geometric_normal(gp.w);
    vec4 en = texelFetch(gb_normal, px, 0);
    vec3 n = oct_decode(en.xy), tg = oct_decode(en.zw);
    MaterialData m = mats[uint(uvm.z)];
    vec3 v = normalize(cam.eye.xyz - pos);
    float ndv = max(dot(n, v), 1e-4);
    vec3 albedo = m.albedo_kind.rgb;
    int kind = int(m.albedo_kind.w + 0.5);
    m = material_at(m, uvm.xy, material_textures);
    albedo = m.albedo_kind.rgb;
    gather_neighbours(pos, n);
    pix_frame = avs_frame(n);
    SG cosg = sg_clamped_cosine(n);
    uint nl = min(pc.lobe_count, 64u), nk = min(pc.key_count, 16u);
    // ray origin off the surface along the geometric normal (as the shadow fields')
    vec3 po = pos + ng * 1e-3 * max(1.0, length(pos));
    float roughness = clamp(kind == 1 ? sqrt(2.0 / (m.extra.x + 2.0)) : m.spec_rough.w, 0.02, 1.0);
    // The glossy term. Ratio (specular_mode 2): the material model's unshadowed glossy term (the
    // `env` technique's split sum) times the light-weighted SSDF visibility of the specular SG
    // lobe x cosine gj: sum_k e_k V_k / sum_k e_k over the lighting lobes and the key lights split
    // off the map (e_k: the luminance of lobe k's inner product with gj; V_k: the visible fraction
    // of their product, through the SSDFs, or for a key light whose shadows are traced, through
    // rays in the product's cone), as isg's (isg_lobes.glsl's glossy steps); a lobe narrower than
    // about 4 degrees (lambda > 256), or one no light reaches, takes its own visible fraction.
    // Otherwise eq. 9 with the Beckmann warp (Wang et al. 2009), m = roughness^2 as the
    // reference's SG mode: mu Gamma_L(a, lambda) times gj's visible fraction.
    bool ratio = kind != 0 && pc.specular_mode == 2u;
    vec3 amp = vec3(0.0), glossy = vec3(0.0), gamma_l = vec3(0.0);
    SG gj = cosg;
    bool glossy_vis = false;
    if (kind != 0) {
        gj = sg_product(sg_specular_lobe(kind, n, v, ndv, m.extra.x, roughness, m.spec_rough.rgb, amp), cosg);
        if (ratio) {
            glossy = env_glossy(n, tg, v, m);
            glossy_vis = max(glossy.r, max(glossy.g, glossy.b)) > 0.0;
        } else {
            if (pc.specular_mode == 0u) {
                gamma_l = pf_eval(gj.axis, gj.lambda) * sg_sphere_integral(gj);
            } else {
                for (uint k = 0u; k < pc.lobe_count; ++k) {
                    SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
                    gamma_l += lobes[2u * k + 1u].rgb * sg_inner_product(l, gj);
                }
            }
            glossy_vis = max(gamma_l.r, max(gamma_l.g, gamma_l.b)) > 0.0;
        }
    }
    bool own_only = !ratio || !shadows_on() || gj.lambda > 256.0;
    bool traced = (pc.flags & 2u) != 0u;
    // Every visibility query of the pixel in one loop with one call of visible() (one inlined
    // copy of the SSDF integration; lavapipe compiles every inlined copy): items 0 .. nl - 1
    // the diffuse lighting lobes through the clamped cosine, then (with a glossy term) the
    // lighting lobes and key lights through gj (the ratio's, unless own_only), then gj itself
    // (own_only, or no light reaching it).
    uint n_glossy = glossy_vis ? (own_only ? 0u : nl + nk) + 1u : 0u;
    // Each key light's rays traced once (cone_rays_mask), for its diffuse light and for its share
    // of a glossy lobe gj nearly flat over the light: gj.lambda <= KEY_REUSE lambda_l, so that gj
    // varies by less than about 10 % over the light's disk (angular radius 2 / sqrt(lambda_l)),
    // the rays weighted by gj. A sharper lobe's share takes rays of its own in the cone of its
    // product with the light (below): weighting the light's rays by it instead measured
    // turning_light's glossy floor 0.0420 -> 0.0457 rmse/mean at 160x120.
    const float KEY_REUSE = 0.05;
    uint kmask[16];
    float kfrac[16];
    vec2 khits[16];
    for (uint k = 0u; k < nk; ++k) {
        kmask[k] = 0u;
        kfrac[k] = 1.0;
        khits[k] = vec2(0.0);
        if (!traced) continue;
        SG l = sg_make(key[2u * k].xyz, key[2u * k].w, 1.0);
        bool lit = max(sg_cosine_integral(l, n), 0.0) > 0.0
            || (n_glossy > 1u && gj.lambda <= KEY_REUSE * l.lambda && sg_inner_product(l, gj) > 0.0);
        if (!lit) continue;
        float rad = 2.0 / sqrt(max(l.lambda, 1e-4));
        // key_rays = predicted (flags bit 2): where the interpolated SSDF puts the nearest
        // visibility boundary farther from the light's axis than its disk plus two texels, the
        // centre ray alone confirms the light wholly seen (or hidden); the disk where it disagrees
        if ((pc.flags & 4u) != 0u && shadows_on()) {
            float d = ssdf_at(l.axis);
            float margin = atan(0.9 * rad) + 2.0 * avs_texel_angle(pc.r);
            vec3 dc = cone_cell_dir(po, l.axis, rad, 0);
            if (abs(d) > margin && dot(dc, ng) > 0.0) {
                float th = kd_trace_order(po, dc, 0.0, 1e30, true, false).t;  // its distance is kept
                bool seen = th < 0.0;
                if (seen == (d > 0.0)) {
                    if (!seen) khits[k] = vec2(th, 1.0);
                    kmask[k] = (1u << 16u) | (seen ? 1u : 0u);
                    kfrac[k] = seen ? 1.0 : 0.0;
                    continue;
                }
            }
        }
        kmask[k] = cone_rays_mask(po, l.axis, rad, ng, khits[k]);
        kfrac[k] = key_penumbra_fraction(kmask[k], po, l.axis, rad, ng);
    }
    // Lobes that bring less than LOBE_CULL of a ratio's light (the diffuse lobes' irradiance with
    // diffuse_ratio, the glossy items' light in gj) are left out of both its sums: the ratio
    // takes the visible share of the lobes that carry the light, at fewer SSDF lookups (0.02
    // measured coarse 0.0399 -> 0.0416 rmse/mean at 160x120; 0.01 left it at 0.0399).
    const float LOBE_CULL = 0.01;
    float ed_sum = 0.0, eg_sum = 0.0;
    for (uint k = 0u; k < nl; ++k) {
        SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        ed_sum += dot(lobes[2u * k + 1u].rgb, vec3(0.2126, 0.7152, 0.0722)) * max(sg_cosine_integral(l, n), 0.0);
        if (n_glossy > 1u) eg_sum += dot(lobes[2u * k + 1u].rgb, vec3(0.2126, 0.7152, 0.0722)) * max(sg_inner_product(l, gj), 0.0);
    }
    for (uint k = 0u; k < nk && n_glossy > 1u; ++k) {
        SG l = sg_make(key[2u * k].xyz, key[2u * k].w, 1.0);
        eg_sum += dot(key[2u * k + 1u].rgb, vec3(0.2126, 0.7152, 0.0722)) * max(sg_inner_product(l, gj), 0.0);
    }
    float ed_cut = pc.diffuse_ratio != 0u ? LOBE_CULL * ed_sum : 0.0, eg_cut = LOBE_CULL * eg_sum;
    vec3 diffuse = vec3(0.0), diffuse_open = vec3(0.0);
    float num = 0.0, den = 0.0, vs = 1.0;
    for (uint it = 0u; it < nl + n_glossy; ++it) {
        SG g = gj;
        vec3 ed = vec3(0.0);
        float eg = 0.0;
        bool cone = false, own = false;
        if (it < nl) {
            SG l = sg_make(lobes[2u * it].xyz, lobes[2u * it].w, 1.0);
            ed = lobes[2u * it + 1u].rgb * max(sg_cosine_integral(l, n), 0.0);
            if (max(ed.r, max(ed.g, ed.b)) <= 0.0 || dot(ed, vec3(0.2126, 0.7152, 0.0722)) < ed_cut) continue;
            g = sg_product(l, cosg);
        } else if (it + 1u < nl + n_glossy) {
            uint k = it - nl;
            vec4 al = k < nl ? lobes[2u * k] : key[2u * (k - nl)];
            vec3 mu = k < nl ? lobes[2u * k + 1u].rgb : key[2u * (k - nl) + 1u].rgb;
            SG l = sg_make(al.xyz, al.w, 1.0);
            eg = dot(mu, vec3(0.2126, 0.7152, 0.0722)) * sg_inner_product(l, gj);
            if (!(eg > 0.0) || eg < eg_cut) continue;
            g = sg_product(l, gj);
            // a key light's reflection through rays toward it (as its diffuse light)
            cone = k >= nl && traced;
        } else {
            own = true;
            if (!own_only && den > 0.0) continue;
        }
        float vis;
        if (cone && gj.lambda <= KEY_REUSE * key[2u * (it - nl - nl)].w) {
            SG l = sg_make(key[2u * (it - nl - nl)].xyz, key[2u * (it - nl - nl)].w, 1.0);
            vis = cone_mask_weighted(kmask[it - nl - nl], po, l.axis, 2.0 / sqrt(max(l.lambda, 1e-4)), gj);
        } else {
            vis = cone ? cone_rays_visibility(po, g.axis, 2.0 / sqrt(max(g.lambda, 1e-4)), ng) : visible(g);
        }
        if (it < nl) {
            diffuse += ed * vis;
            diffuse_open += ed;
        } else if (own) {
            vs = vis;
        } else {
            num += eg * vis;
            den += eg;
        }
    }
    if (!own_only && den > 0.0) vs = clamp(num / den, 0.0, 1.0);
    if (pc.diffuse_ratio != 0u) diffuse = irr_ratio(n, diffuse, diffuse_open);
    // (bit 5 is set only with traced key-light shadows)
    bool split_key = (pc.flags & 32u) != 0u;
    vec3 key_open = vec3(0.0);
    float key_num = 0.0, key_den = 0.0, key_t = 0.0, key_tw = 0.0, key_rad = 0.0;
    if (pc.key_count > 0u) {
        for (uint k = 0u; k < nk; ++k) {
            vec4 axis_lambda = key[2u * k];
            vec3 mu = key[2u * k + 1u].rgb;
            // shadows off (flags bit 1 clear): the same light, unshadowed
            vec3 e = mu * max(sg_cosine_integral(sg_make(axis_lambda.xyz, axis_lambda.w, 1.0), n), 0.0);
            if (split_key) {
                float le = dot(e, vec3(0.2126, 0.7152, 0.0722));
                key_open += e;
                key_num += le * kfrac[k];
                key_den += le;
                key_rad += le * 2.0 / sqrt(max(axis_lambda.w, 1e-4));
                if (khits[k].y > 0.0) {
                    key_t += le * khits[k].x / khits[k].y;
                    key_tw += le;
                }
            } else {
                diffuse += traced ? e * kfrac[k] : e;
            }
        }
    }
    if (split_key) {
        vec3 kd = material_reflected(material_diffuse_albedo(m, ndv) / PI * key_open, n, v);
        imageStore(key_out, px, vec4(kd, key_den > 0.0 ? clamp(key_num / key_den, 0.0, 1.0) : 1.0));
        imageStore(key_aux, px, vec4(key_tw > 0.0 ? key_t / key_tw : 0.0, key_den > 0.0 ? key_rad / key_den : 0.0, 0.0, 0.0));
    }
    vec3 color = material_diffuse_albedo(m, ndv) / PI * diffuse;
    color += local_lights(pos, n, tg, ng, v, albedo, m);
    if (glossy_vis) color += ratio ? glossy * vs : amp * gamma_l * vs;
    imageStore(hdr, px, vec4(material_reflected(max(color, vec3(0.0)), n, v) + material_emission(m), 1.0));
}
