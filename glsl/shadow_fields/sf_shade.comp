#version 450
// Shadow fields, per pixel. Diffuse: mode 0 (pixel) evaluates Fig. 3 of the paper at the
// G-buffer point with the clamped-cosine transfer of its normal (no self-occlusion at pixels):
// the other objects' visibility from their shadow fields (triple products), local lights
// through their source radiance fields and the environment SH (double products); mode 1
// (vertex) reads the per-vertex radiance (self-occlusion transfer included, computed by
// sf_points.comp for the visible vertices and interpolated by the sf_vertex raster pass).
// Glossy materials add the material model's glossy term (env_shade.glsl, as the `env`
// technique) times the occluders' visibility along the reflection (with key lights split off:
// each key light's share through rays toward it, light_rays.glsl's key_light_glossy_share), and
// the local lights' specular lobe, times the visibility toward the light of the occluders nearer
// than it. With srf = 0 local lights are evaluated pointwise (BRDF
// times the occluders' visibility toward the light) instead of through their fields; with
// traced = 1 (light_shadows = traced) pointwise and shadowed by rays through the kd-tree.
// Sky pixels show the environment.
#include "common.glsl"
#define SF_B0 7
#include "sf.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
layout(set = 0, binding = 12) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 13) uniform sampler2D vtx_radiance;
layout(set = 0, binding = 14) uniform sampler2DArray material_textures;
#include "material.glsl"
#include "lights.glsl"
#include "env_shade.glsl"
// The frame's kd-tree (include/kdtree.glsl): the local lights' shadow rays (traced = 1).
layout(set = 0, binding = 15) uniform usamplerBuffer kd_tris;
layout(set = 0, binding = 16) uniform usamplerBuffer kd_nodes;
layout(set = 0, binding = 17) uniform usamplerBuffer kd_refs;
layout(set = 0, binding = 18) readonly buffer KdHeader { uint kd_hdr[]; };
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"
#include "light_rays.glsl"
// The environment's key lights split off from its SH (SfOptions::key_lights), 2 per light: world
// axis + lambda, rgb amplitude.
layout(set = 0, binding = 19) readonly buffer KeyLights { vec4 key[]; };
// traced: local lights pointwise, shadowed by rays through the kd-tree (light_shadows = traced;
// srf is then 0); key_count: key lights (traced only)
layout(push_constant) uniform Push { uint n_inst; uint tensor_count; uint light_count; uint srf; uint window; uint mode; uint traced; uint key_count; uint glossy_sh; } pc;

// Irradiance from the key lights at a point of normal n (offset point p, geometric normal ng).
vec3 key_lights_irradiance(vec3 p, vec3 n, vec3 ng) {
    vec3 sum = vec3(0.0);
    for (uint k = 0u; k < pc.key_count; ++k) sum += key_light_irradiance(key[2u * k], key[2u * k + 1u].rgb, p, n, ng);
    return sum;
}

// Local lights (as shade_env.comp's local_lights, same BRDFs), pointwise: the specular lobe
// always, the diffuse lobe only with srf = 0 (else it comes through the source radiance fields),
// each shadowed by the order-4 visibility toward the light of the other objects nearer than it.
// With `reflect_query`, one more query in the same loop: the occluders' visibility along r (the
// glossy term's), in `reflect_vis`. One call of sf_visibility_along serves them all (one
// inlined copy of the occluders' lookups: lavapipe compiles every inlined copy).
vec3 local_lights(vec3 pos, vec3 n, vec3 t, vec3 ng, vec3 v, vec3 albedo, MaterialData m, uint self_inst, bool reflect_query, vec3 r, out float reflect_vis) {
    vec3 sum = vec3(0.0);
    reflect_vis = 1.0;
    uint count = pc.light_count + (reflect_query ? 1u : 0u);
    for (uint i = 0u; i < count; ++i) {
        bool reflection = i == pc.light_count;
        vec3 wi = r, e = vec3(0.0), f = vec3(0.0);
        float dist = 1e30, ndl = 0.0;
        if (!reflection) {
            LightData l = lights[i];
            e = light_incident(l, pos, n, ng, wi, dist, ndl);
            if (ndl <= 0.0) continue;
            // a directional light (kind 3) has no source radiance field: its diffuse lobe is here too
            bool via_srf = pc.srf != 0u && int(l.pos_kind.w + 0.5) != 3;
            f = light_brdf(wi, n, t, v, via_srf ? vec3(0.0) : albedo, m);
            if (all(equal(f, vec3(0.0)))) continue;
            if (pc.traced != 0u) {
                sum += light_rays_visibility(l, pos + ng * 1e-3 * max(1.0, length(pos))) * f * e * ndl;
                continue;
            }
        }
        float vis = sf_visibility_along(pos, wi, self_inst, pc.n_inst, dist);
        if (reflection) {
            reflect_vis = vis;
        } else {
            sum += vis * f * e * ndl;
        }
    }
    return sum;
}

// Order-4 SH of max(n.w, 0) / pi: A_l / pi * Y_lm(n), A = (pi, 2pi/3, pi/4, 0), Condon-Shortley real SH.
void cosine_transfer(vec3 n, out float t[16]) {
    float x = n.x, y = n.y, z = n.z;
    // basis values (penumbra_math::sh convention)
    float b[16];
    b[0] = 0.282094792;
    b[1] = -0.488602512 * y;
    b[2] = 0.488602512 * z;
    b[3] = -0.488602512 * x;
    b[4] = 1.092548431 * x * y;
    b[5] = -1.092548431 * y * z;
    b[6] = 0.315391565 * (3.0 * z * z - 1.0);
    b[7] = -1.092548431 * x * z;
    b[8] = 0.546274215 * (x * x - y * y);
    // band 3 has A_3 = 0
    for (int e = 9; e < 16; e++) b[e] = 0.0;
    t[0] = b[0];
    for (int e = 1; e < 4; e++) t[e] = (2.0 / 3.0) * b[e];
    for (int e = 4; e < 9; e++) t[e] = 0.25 * b[e];
    for (int e = 9; e < 16; e++) t[e] = 0.0;
}

// The normalized lobe exp(lam (a.w - 1)) (integral 1) as an order-4 SH transfer:
// c_lm = A_l(lam) Y_lm(a), A_l the lobe's mean of the Legendre polynomial P_l (von Mises-Fisher:
// A_1 = coth lam - 1/lam, A_2 = 1 - 3 A_1 / lam, A_3 = A_1 - 5 A_2 / lam; their series below
// lam = 0.5, where the differences cancel). cosine_transfer is the same for max(n.w, 0) / pi.
void lobe_transfer(vec3 a, float lam, out float t[16]) {
    float a1, a2, a3;
    if (lam < 0.5) {
        float l2 = lam * lam;
        a1 = lam / 3.0 - lam * l2 / 45.0;
        a2 = l2 / 15.0;
        a3 = lam * l2 / 105.0;
    } else {
        float e = exp(-2.0 * min(lam, 40.0));
        a1 = (1.0 + e) / (1.0 - e) - 1.0 / lam;
        a2 = 1.0 - 3.0 * a1 / lam;
        a3 = a1 - 5.0 * a2 / lam;
    }
    sh16_basis(a, t);
    for (int e = 1; e < 4; e++) t[e] *= a1;
    for (int e = 4; e < 9; e++) t[e] *= a2;
    for (int e = 9; e < 16; e++) t[e] *= a3;
}

// glossy = transfer: the key lights' glossy radiance (the part of the environment split off its
// SH), each light's lobe against the specular lobe times the cosine (gj, amplitude amp), seen
// through rays across their product (light_rays.glsl's key_light_lobe_visibility, as
// key_light_glossy_share, in rgb).
vec3 key_lights_glossy(vec3 amp, SG gj, vec3 p, vec3 ng) {
    vec3 sum = vec3(0.0);
    for (uint k = 0u; k < pc.key_count; ++k) {
        vec4 al = key[2u * k];
        SG l = sg_make(al.xyz, al.w, 1.0);
        float e = sg_inner_product(l, gj);
        if (!(e > 0.0)) continue;
        sum += key[2u * k + 1u].rgb * amp * e * key_light_lobe_visibility(l, gj, p, ng);
    }
    return sum;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 uvm = texelFetch(gb_uv_mat, p, 0);
    if (uvm.w < 0.5) {
        vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
        vec3 dir = far_p.xyz / far_p.w - cam.eye.xyz;
        imageStore(hdr, p, vec4(env_background(dir), 1.0));
        return;
    }
    vec4 gp = texelFetch(gb_position, p, 0);
    vec3 pos = gp.xyz, ng = gb_geometric_normal(gp.w);
    vec4 en = texelFetch(gb_normal, p, 0);
    vec3 n = oct_decode(en.xy), tg = oct_decode(en.zw);
    MaterialData m = material_at(mats[uint(uvm.z)], uvm.xy, material_textures);
    uint self_inst = uint(uvm.w + 0.5) - 1u;
    vec3 v = normalize(cam.eye.xyz - pos);
    int kind = int(m.albedo_kind.w + 0.5);
    vec3 r = reflect(-v, n);
    float ndv = max(dot(n, v), 1e-4);
    // glossy = transfer: the specular lobe times the cosine as an SG (its amplitude amp), whose
    // normalized shape is the second transfer of the one sf_shade_point call
    bool glossy_sh = pc.glossy_sh != 0u && kind != 0;
    vec3 amp = vec3(0.0);
    SG gj;
    gj.axis = n;
    gj.lambda = 1.0;
    gj.mu = 1.0;
    float ug[16];
    sf_zero(ug);
    if (glossy_sh) {
        // Ashikhmin-Shirley as the Cook-Torrance lobe of its width (env_alpha)
        SG spec = sg_specular_lobe(kind == 1 ? 1 : 2, n, v, ndv, m.extra.x, env_roughness(m), m.spec_rough.rgb, amp);
        gj = sg_product(spec, sg_clamped_cosine(n));
        lobe_transfer(gj.axis, gj.lambda, ug);
    }
    vec3 diffuse, glossy_env = vec3(0.0);
    if (pc.mode == 1u && !glossy_sh) {
        diffuse = texelFetch(vtx_radiance, p, 0).rgb;
    } else {
        // pixel mode: the diffuse transfer (and the glossy lobe's); vertex mode: the glossy lobe's alone
        float u[16];
        if (pc.mode == 1u) u = ug; else cosine_transfer(n, u);
        uint n_light = pc.srf != 0u && pc.mode == 0u ? pc.light_count : 0u;
        vec3 c1 = sf_shade_point(pos, ng, self_inst, pc.n_inst, n_light, pc.tensor_count, pc.window, u, glossy_sh && pc.mode == 0u, ug, glossy_env);
        if (pc.mode == 1u) {
            diffuse = texelFetch(vtx_radiance, p, 0).rgb;
            glossy_env = c1;
        } else {
            diffuse = c1;
        }
    }
    vec3 po = pos + ng * 1e-3 * max(1.0, length(pos));  // ray origin off the surface
    if (pc.key_count > 0u) diffuse += key_lights_irradiance(po, n, ng) / PI;
    vec3 color = max(material_diffuse_albedo(m, dot(n, v)) * diffuse, vec3(0.0));
    // Glossy materials: the material model's glossy environment term (the "env" technique's),
    // shadowed by the occluders' visibility along the reflection; or (glossy = transfer) the
    // lobe's SH transfer through the fields times its directional albedo, the key lights apart.
    float reflect_vis;
    vec3 lit = local_lights(pos, n, tg, ng, v, m.albedo_kind.rgb, m, self_inst, kind != 0 && pc.key_count == 0u && !glossy_sh, r, reflect_vis);
    if (glossy_sh) {
        color += max(glossy_env, vec3(0.0)) * env_specular_albedo(m, ndv);
        if (pc.key_count > 0u) color += key_lights_glossy(amp, gj, po, ng);
    } else if (kind != 0) {
        vec3 glossy = env_glossy(n, tg, v, m);
        float vis;
        if (pc.key_count > 0u) {
            // the key lights' reflections through their own rays, the rest along the reflection
            vec3 amp;
            SG spec = sg_specular_lobe(kind, n, v, ndv, m.extra.x, env_roughness(m), m.spec_rough.rgb, amp);
            SG gj = sg_product(spec, sg_clamped_cosine(n));
            vec2 acc = vec2(0.0);
            for (uint k = 0u; k < pc.key_count; ++k)
                key_light_glossy_share(key[2u * k], key[2u * k + 1u].rgb, amp, gj, po, ng, acc);
            vis = glossy_share(acc, dot(glossy, vec3(0.2126, 0.7152, 0.0722)), cone_rays_visibility(po, r, env_alpha(m), ng));
        } else {
            vis = reflect_vis;
        }
        color += vis * glossy;
    }
    color += lit;
    imageStore(hdr, p, vec4(material_reflected(color, n, v) + material_emission(m), 1.0));
}
