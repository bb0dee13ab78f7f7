// ISG shading (Iwasaki et al. 2012) per pixel: environment as K SG lobes; diffuse: per lobe, the
// unshadowed SG-cosine integral times the ISG visible fraction of the lobe times the cosine SG;
// specular: one SG lobe of the BRDF (Blinn-Phong / Cook-Torrance warp; Ashikhmin-Shirley as the
// paper's seven, sg.glsl sg_as_lobes, or with `as_lobes = 1` a Cook-Torrance lobe of its
// roughness) times the cosine SG, Gamma_L = int L G_j from the
// prefiltered environment maps (or from the lighting lobes), times the ISG visible fraction of
// G_j (eq. 9); with glossy ratio (default) the glossy term is the material model's unshadowed
// one (env_shade.glsl, the `env` technique's) times that visible fraction; with diffuse_ratio (default) the diffuse term is the map's exact irradiance times
// the lobes' visible share (include/irradiance.glsl). Local lights shadowed by rays. Included by isg_shade.comp (per pixel) and
// isg_shade_vertex.comp (ISG_PER_VERTEX: the visibilities come interpolated from the mesh
// vertices, isg_vertex.comp + isg_vertex.vert/.frag; pixels no vertex triangle covered fall
// back to the per-pixel evaluation).
#ifndef PENUMBRA_ISG_SHADE_GLSL
#define PENUMBRA_ISG_SHADE_GLSL
#include "common.glsl"
#include "sg.glsl"

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
layout(set = 0, binding = 10) readonly buffer Lobes { vec4 lobes[]; };  // 2 per lobe: axis+lambda, rgb mu
#define ISG_TABLE_BINDING 9
#define ISG_NODES_BINDING 11
#define ISG_MAX_SIDE 32
#define ISG_TRIS_BINDING 13
#define ISG_TRI_NODES_BINDING 14
#include "isg.glsl"
#ifdef ISG_PER_VERTEX
// Interpolated per-vertex visibilities: rgb diffuse (shadowed / unshadowed irradiance), a
// specular (ISG visible fraction of G_j); r < 0: no vertex triangle covers the pixel.
layout(set = 0, binding = 16) uniform sampler2D vertex_vis;
#endif
// Prefiltered environment (penumbra_math::envmap::prefilter, Gamma_L / int G): [0] level count,
// per level i at 1 + 4 i: lambda, width, height, offset of its RGB texels in this array.
layout(set = 0, binding = 12) readonly buffer Prefiltered { float pf[]; };
// The environment's irradiance map (passes::lighting::irradiance_env): the ratio estimator's
// unshadowed diffuse term.
layout(set = 0, binding = 15) readonly buffer Irradiance { float irr[]; };
#include "irradiance.glsl"
// The frame's kd-tree (include/kdtree.glsl): local lights' shadow rays through the meshes
// (flags bit 2), after the per-vertex image at 16.
#ifdef ISG_PER_VERTEX
#define ISG_KD_BINDING 17
#else
#define ISG_KD_BINDING 16
#endif
layout(set = 0, binding = ISG_KD_BINDING) uniform usamplerBuffer kd_tris;
layout(set = 0, binding = ISG_KD_BINDING + 1) uniform usamplerBuffer kd_nodes;
layout(set = 0, binding = ISG_KD_BINDING + 2) uniform usamplerBuffer kd_refs;
layout(set = 0, binding = ISG_KD_BINDING + 3) readonly buffer KdHeader { uint kd_hdr[]; };
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"
layout(push_constant) uniform Push {
    uint light_count;
    uint lobe_count;
    int node_count;
    int patch_side;
    float lod;
    uint flags;  // bit 0: no shadows (debug); bit 1: local lights unshadowed; bit 2: their shadow rays through the meshes (kd-tree), not the spheres; bit 3: environment visibility traced through the kd-tree (traced_visible); bit 4: isg_paper_fit, bit 5: isg_paper_rule (isg.glsl); bit 6: Ashikhmin-Shirley as seven SG lobes (sg.glsl sg_as_lobes)
    float min_fraction;
    uint specular_mode;  // 0: Gamma_L from the prefiltered maps (paper), 1: from the lighting SGs, 2: ratio (env_shade.glsl's glossy term x the ISG visible fraction)
    int tri_node_count;  // thin-shell triangle BVH nodes
    uint diffuse_ratio;  // 1: the map's irradiance x the lobes' visible share; 0: the SG lobes alone
} pc;

// Whether the segment from p along unit w for length d is blocked: through the meshes (the
// frame's kd-tree, flags bit 2) or through the sphere BVH and the thin-shell triangles.
bool light_segment_blocked(vec3 p, vec3 w, float d) {
    if ((pc.flags & 4u) != 0u) return kd_trace(p, w, 0.0, d * (1.0 - 1e-4), true).t >= 0.0;
    return isg_segment_blocked(p, w, d, pc.node_count, pc.tri_node_count);
}

// Unoccluded fraction of a local light seen from p (offset shading point). Point and spot lights:
// one ray (hard shadow). Sphere lights: lights.glsl's LIGHT_DISK_POINTS targets on the disk
// facing p.
float light_visibility(vec3 p, vec3 to_light, float radius) {
    if ((pc.flags & 3u) != 0u) return 1.0;
    float d = length(to_light);
    if (!(d > 0.0)) return 1.0;
    // one loop, one call site of the traversals (lavapipe compiles every inlined copy)
    int count = radius <= 0.0 ? 1 : LIGHT_DISK_POINTS;
    float vis = 0.0, cnt = 0.0;
    for (int i = 0; i < count; ++i) {
        if (disk_settled(i, vis, cnt)) break;
        cnt += 1.0;
        vec3 q = radius <= 0.0 ? to_light : light_disk_target(to_light, radius, disk_ray(i));
        float len = length(q);
        vis += light_segment_blocked(p, q / len, len) ? 0.0 : 1.0;
    }
    return vis / cnt;
}

vec3 local_lights(vec3 pos, vec3 p, vec3 n, vec3 t, vec3 ng, vec3 v, vec3 albedo, MaterialData m) {
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < pc.light_count; ++i) {
        LightData l = lights[i];
        vec3 wi;
        float dist, ndl;
        vec3 e = light_incident(l, pos, n, ng, wi, dist, ndl);
        if (ndl <= 0.0) continue;
        vec3 f = light_brdf(wi, n, t, v, albedo, m);
        int lk = int(l.pos_kind.w + 0.5);
        float vis = light_visibility(p, light_vector(l, p), lk == 2 ? l.extra.x : 0.0);
        sum += f * e * ndl * vis;
    }
    return sum;
}

#include "env_background.glsl"

#include "prefiltered.glsl"

// The visible fraction of g estimated by tracing: ISG_TRACED_SAMPLES directions drawn from g
// (stratified in cos theta, golden-angle azimuths, rotated per pixel) above the tangent plane,
// each a shadow ray through the frame's kd-tree (`visibility = traced`, flags bit 3: the
// visibility the sphere proxies and the ISG approximate, for measuring their error apart from
// the SG lighting's).
#define ISG_TRACED_SAMPLES 96
float traced_visible(vec3 p, vec3 n, SG g) {
    vec3 fz = g.axis;
    vec3 fx = normalize(abs(fz.x) < 0.9 ? cross(vec3(1.0, 0.0, 0.0), fz) : cross(vec3(0.0, 1.0, 0.0), fz));
    vec3 fy = cross(fz, fx);
    uvec2 q = uvec2(gl_GlobalInvocationID.xy);
    uint hsh = (q.x * 1973u + q.y * 9277u + 26699u) * 0x9E3779B9u;
    hsh ^= hsh >> 15;
    hsh *= 0x2C1B3C6Du;
    hsh ^= hsh >> 12;
    float r0 = float(hsh & 0xffffu) / 65536.0, r1 = float(hsh >> 16) / 65536.0;
    float lam = max(g.lambda, 1e-4);
    float span = 1.0 - exp(-2.0 * lam);
    float vis = 0.0, cnt = 0.0;
    for (int k = 0; k < ISG_TRACED_SAMPLES; ++k) {
        float u = fract((float(k) + r0) / float(ISG_TRACED_SAMPLES));
        float ct = clamp(1.0 + log(max(1.0 - u * span, 1e-30)) / lam, -1.0, 1.0);
        float st = sqrt(max(1.0 - ct * ct, 0.0));
        float ph = 6.28318531 * fract(float(k) * 0.61803399 + r1);
        vec3 w = (fx * cos(ph) + fy * sin(ph)) * st + fz * ct;
        if (dot(w, n) <= 0.0) continue;
        cnt += 1.0;
        vis += kd_trace(p, w, 0.0, 1e30, true).t >= 0.0 ? 0.0 : 1.0;
    }
    return cnt > 0.0 ? vis / cnt : 1.0;
}

float visible(vec3 p, vec3 n, SG g) {
    if ((pc.flags & 1u) != 0u) return 1.0;
    if ((pc.flags & 8u) != 0u) return traced_visible(p, n, g);
    return isg_visible(p, n, g.axis, g.lambda, pc.node_count, pc.tri_node_count, pc.patch_side, pc.lod);
}

#include "isg_lobes.glsl"

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (px.x >= size.x || px.y >= size.y) return;
    isg_paper_fit = (pc.flags & 16u) != 0u;
    isg_paper_rule = (pc.flags & 32u) != 0u;
    vec4 uvm = texelFetch(gb_uv_mat, px, 0);
    if (uvm.w < 0.5) {
        vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
        imageStore(hdr, px, vec4(env_background(far_p.xyz / far_p.w - cam.eye.xyz), 1.0));
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
    SG cosg = sg_clamped_cosine(n);
    // Offset the shading point along the normal (G-buffer precision).
    vec3 p = pos + n * 1e-3 * max(1.0, length(pos));
    vec4 vvis = vec4(-1.0);
#ifdef ISG_PER_VERTEX
    vvis = texelFetch(vertex_vis, px, 0);
#endif
    bool per_vertex = vvis.r >= 0.0;
    const vec3 lum = vec3(0.2126, 0.7152, 0.0722);
    vec3 diffuse = vec3(0.0), unshadowed = vec3(0.0);
    uint nl = min(pc.lobe_count, 64u);
    if (per_vertex) {
        if (pc.diffuse_ratio != 0u) {
            diffuse = irr_eval(n);
        } else {
            for (uint k = 0u; k < nl; ++k) {
                SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
                diffuse += lobes[2u * k + 1u].rgb * max(sg_cosine_integral(l, n), 0.0);
            }
        }
        diffuse *= (pc.flags & 1u) != 0u ? vec3(1.0) : clamp(vvis.rgb, 0.0, 1.0);
    }
    float roughness = clamp(kind == 1 ? sqrt(2.0 / (m.extra.x + 2.0)) : m.spec_rough.w, 0.02, 1.0);
    // Ashikhmin-Shirley as seven SG lobes (flags bit 6, per pixel: the vertices carry no tangent)
    // or, as the other BRDFs, one (a Cook-Torrance lobe of the material's roughness).
    bool as7 = kind == 3 && (pc.flags & 64u) != 0u && !per_vertex;
    SG as_g[SG_AS_LOBES];
    vec3 as_w[SG_AS_LOBES];
    if (as7) {
        sg_as_lobes(brdf_frame(n, tg), v, m.extra.x, m.extra.w, m.spec_rough.rgb, as_g, as_w);
        for (int k = 0; k < SG_AS_LOBES; ++k) as_g[k] = sg_product(as_g[k], cosg);
    }
    // Glossy, specular_mode 2 (ratio): the material model's unshadowed glossy term (the `env`
    // technique's split sum, env_shade.glsl) times the light-weighted visible share of the BRDF's
    // lobes (isg_lobes.glsl; Ashikhmin-Shirley's seven weighted by their BRDF weights'
    // luminance, lobes under 1 % of the total weight left out: the two outermost carry 0.1 %
    // each). The one SG lobe of eq. 9 loses the lobe's Fresnel and masking energy
    // (balls_on_dish's Cook-Torrance dish came out about 10 % dark with shadows off).
    // Otherwise eq. 9: per BRDF lobe G_j (times the cosine), mu_j Gamma_L(a_j, lambda_j) times
    // its visible fraction. One lobe: the Beckmann warp (Wang et al. 2009), m = roughness^2 as
    // the reference's SG mode; Ashikhmin-Shirley with bit 6: its seven.
    bool ratio = kind != 0 && pc.specular_mode == 2u;
    vec3 glossy = ratio ? env_glossy(n, tg, v, m) : vec3(0.0);
    bool ratio_traced = ratio && max(glossy.r, max(glossy.g, glossy.b)) > 0.0 && !per_vertex && (pc.flags & 1u) == 0u;
    int gcount = kind == 0 ? 0 : (as7 ? SG_AS_LOBES : 1);
    SG g1;
    float wsum = 0.0;
    if (ratio_traced) {
        vec3 amp;
        g1 = sg_product(sg_specular_lobe(kind, n, v, ndv, m.extra.x, roughness, m.spec_rough.rgb, amp), cosg);
        for (int j = 0; j < gcount; ++j) wsum += as7 ? dot(as_w[j], lum) : 1.0;
    }
    float num = 0.0, den = 0.0;
    vec3 spec9 = vec3(0.0);
    // Every visibility query goes through one call of isg_lobes_shadowed (one inlined ISG
    // traversal; lavapipe compiles every inlined copy, and four took this shader's first compile
    // to 46 s): query 0 the diffuse lighting lobes through the clamped cosine (per pixel), query
    // 1 + j the glossy lobe j, in up to two steps: the lighting lobes through it, then its own
    // visible fraction (eq. 9; a lobe narrower than about 4 degrees; no lighting lobe reaching
    // it: isg_lobes.glsl's glossy steps).
    for (int q = 0; q <= gcount; ++q) {
        SG kernel = cosg;
        bool need = q == 0 && !per_vertex, own_only = false;
        float wj = 1.0;
        vec3 amp = vec3(0.0), gamma_l = vec3(0.0);
        if (q > 0) {
            int j = q - 1;
            if (ratio) {
                wj = as7 ? dot(as_w[j], lum) : 1.0;
                need = ratio_traced && wj > 0.01 * wsum;
                kernel = as7 ? as_g[j] : g1;
            } else {
                if (as7) {
                    kernel = as_g[j];
                    amp = as_w[j];
                    if (max(amp.r, max(amp.g, amp.b)) <= 0.0) continue;
                } else {
                    kernel = sg_product(sg_specular_lobe(kind, n, v, ndv, m.extra.x, roughness, m.spec_rough.rgb, amp), cosg);
                }
                if (pc.specular_mode == 0u) {
                    // Eq. 10: int L G_j = mu_j Gamma_L(a_j, lambda_j), Gamma_L from the prefiltered maps.
                    gamma_l = pf_eval(kernel.axis, kernel.lambda) * sg_sphere_integral(kernel);
                } else {
                    for (uint k = 0u; k < pc.lobe_count; ++k) {
                        SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
                        gamma_l += lobes[2u * k + 1u].rgb * sg_inner_product(l, kernel);
                    }
                }
                if (max(gamma_l.r, max(gamma_l.g, gamma_l.b)) <= 0.0) continue;
                if (per_vertex) {
                    spec9 += amp * gamma_l * ((pc.flags & 1u) != 0u ? 1.0 : clamp(vvis.a, 0.0, 1.0));
                    continue;
                }
                need = true;
                own_only = true;
            }
        }
        if (!need) continue;
        bool glossy_steps = q > 0 && !own_only;
        float open = glossy_steps ? isg_glossy_open(nl, kernel) : 0.0, shadowed = 0.0;
        for (int step = 0; step < 2; ++step) {
            // the diffuse query: step 0; eq. 9: step 1 (the lobe's own fraction); the ratio's
            // glossy lobes: isg_glossy_step's
            if (q == 0 ? step != 0 : (own_only ? step != 1 : !isg_glossy_step(step, kernel, open))) continue;
            vec3 o;
            vec3 r = isg_lobes_shadowed(p, n, nl, pc.min_fraction, kernel, q == 0, step == 1, o);
            if (q == 0) {
                diffuse = r;
                unshadowed = o;
            } else if (own_only) {
                spec9 += amp * gamma_l * r.x;
            } else {
                isg_glossy_fold(step, r, o, shadowed, open);
            }
        }
        if (q > 0 && !own_only) {
            num += wj * shadowed;
            den += wj * open;
        }
    }
    // Diffuse: lobes below min_fraction of the light found visible so far take the mean
    // visibility of those traversed (isg_lobes.glsl).
    if (!per_vertex && pc.diffuse_ratio != 0u) diffuse = irr_ratio(n, diffuse, unshadowed);
    vec3 color = material_diffuse_albedo(m, ndv) / PI * diffuse;
    color += local_lights(pos, p, n, tg, ng, v, albedo, m);
    if (ratio && max(glossy.r, max(glossy.g, glossy.b)) > 0.0) {
        float vs = 1.0;
        if (per_vertex) {
            vs = (pc.flags & 1u) != 0u ? 1.0 : clamp(vvis.a, 0.0, 1.0);
        } else if ((pc.flags & 1u) == 0u) {
            vs = den > 0.0 ? clamp(num / den, 0.0, 1.0) : 1.0;
        }
        color += glossy * vs;
    } else if (kind != 0 && !ratio) {
        color += spec9;
    }
    imageStore(hdr, px, vec4(material_reflected(max(color, vec3(0.0)), n, v) + material_emission(m), 1.0));
}
#endif
