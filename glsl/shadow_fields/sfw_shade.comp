#version 450
// All-frequency shadow fields (passes/src/shadow_fields/wavelet.rs), per pixel: one workgroup
// of 64 invocations per pixel splits the 6 n^2 cube directions. Per direction the product of
// the occluders' visibility maps (each the truncated Haar map of its shell samples, decoded and
// thresholded back to one bit per pixel; bilinear between a shell's 4 nearest samples, linear between its 2 nearest shells; the
// occluder's rotation applied to the direction), the pixel-domain form of the wavelet triple
// product. Diffuse: the exact irradiance at n times the visible share of L cos; glossy: the
// prefiltered environment along the reflection times the visible share of the environment's
// light inside the lobe; local lights analytic, times the occluders' visibility toward them
// (bilinear in the cube face), counting only the occluders nearer than the light. Self-occlusion
// (per-vertex self-visibility maps, interpolated) multiplies the diffuse environment term and
// the first 4 lights.
#include "common.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
layout(set = 0, binding = 7) readonly buffer SfwMaps { uint sfw_maps[]; };
layout(set = 0, binding = 8) readonly buffer SfwShells { uvec4 sfw_shells[]; };  // x first word of its maps, y R

struct SfwInst {
    mat4 world_to_local;
    vec4 center_step;  // xyz shell centre (object space), w shell step 0.2 Vr
    uvec4 info;        // x first shell, y shell count, z casts shadow
    vec4 center_world;  // xyz world position of the shell centre, w world bounding radius
    mat4 local_to_world;
};
layout(set = 0, binding = 9) readonly buffer SfwInsts { SfwInst sfw_inst[]; };
// [0, 6 n^2): world direction of each cube pixel; [6 n^2, 12 n^2): environment radiance x solid angle
layout(set = 0, binding = 10) readonly buffer SfwDirs { vec4 sfw_dirs[]; };
layout(set = 0, binding = 11) readonly buffer Irradiance { float irr[]; };
layout(set = 0, binding = 12) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 13) uniform sampler2DArray material_textures;
// Self-occlusion (sfw_self.comp, interpolated by the sfw_self raster pass): the visible share of
// the environment's L cos (rgb) and the self-visibility toward the first 4 lights; 1 where the
// surface has no maps (or with self-occlusion off).
layout(set = 0, binding = 14) uniform sampler2D self_share;
layout(set = 0, binding = 15) uniform sampler2D self_lights;
#include "material.glsl"
#include "lights.glsl"
#include "env_shade.glsl"
#include "irradiance.glsl"
// The frame's kd-tree (include/kdtree.glsl): the local lights' shadow rays (traced = 1).
layout(set = 0, binding = 16) uniform usamplerBuffer kd_tris;
layout(set = 0, binding = 17) uniform usamplerBuffer kd_nodes;
layout(set = 0, binding = 18) uniform usamplerBuffer kd_refs;
layout(set = 0, binding = 19) readonly buffer KdHeader { uint kd_hdr[]; };
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"
#include "light_rays.glsl"
// The environment's key lights split off its map (SfwOptions::key_lights), 2 per light: world
// axis + lambda, rgb amplitude; the cube's radiance (SfwDirs) and the irradiance map are then the
// rest of the map's.
layout(set = 0, binding = 20) readonly buffer KeyLights { vec4 key[]; };
// traced: the local lights' shadows by rays through the kd-tree (light_shadows = traced);
// key_count: key lights (traced only)
layout(push_constant) uniform Push { uint n_inst; uint light_count; uint n; uint reproject; uint traced; uint key_count; } pc;

#define SFW_PI 3.14159265358979
#define SFW_MAX_OCC 16

// The occluders whose outermost shell contains the pixel's point (nearest first): instance,
// and the 8 (word offset of the sample's map, weight) taps.
shared uint s_count;
shared uint s_inst[SFW_MAX_OCC];
shared uint s_off[SFW_MAX_OCC * 8];
shared float s_w[SFW_MAX_OCC * 8];
shared float s_dist[SFW_MAX_OCC];
// Bounding cone of each occluder seen from the point: axis (xyz) and cos of its half-angle (w;
// -2 when the point is inside the bounding sphere): directions outside it see no occluder.
shared vec4 s_cone[SFW_MAX_OCC];
shared vec4 s_red[64 * 3];
// Object-space positions of the taps' sample points, and of the shaded point per occluder.
shared vec4 s_spos[SFW_MAX_OCC * 8];
shared vec4 s_plocal[SFW_MAX_OCC];

vec3 sfw_polar(float theta, float phi) {
    return vec3(sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta));
}

// Taps of shell `shell` (the field's shell index c, radius step (c + 1) about centre) at the
// point's polar angles, weights scaled by w, into slots k * 8 + base ..
void shell_taps(uint shell, uint c, vec3 centre, float step, float theta, float phi, float w, uint k, uint base) {
    uvec4 sh = sfw_shells[shell];
    uint r = max(sh.y, 1u);
    float rf = float(r);
    float u = clamp(theta / SFW_PI * rf - 0.5, 0.0, rf - 1.0);
    uint s0 = min(uint(floor(u)), r - 1u);
    uint s1 = min(s0 + 1u, r - 1u);
    float fs = u - float(s0);
    float v = fract(phi / (2.0 * SFW_PI)) * rf;
    uint t0 = uint(floor(v)) % r;
    uint t1 = (t0 + 1u) % r;
    float ft = v - floor(v);
    uint words = (6u * pc.n * pc.n + 31u) / 32u;
    s_off[k * 8u + base + 0u] = sh.x + (s0 * r + t0) * words;
    s_off[k * 8u + base + 1u] = sh.x + (s0 * r + t1) * words;
    s_off[k * 8u + base + 2u] = sh.x + (s1 * r + t0) * words;
    s_off[k * 8u + base + 3u] = sh.x + (s1 * r + t1) * words;
    s_w[k * 8u + base + 0u] = w * (1.0 - fs) * (1.0 - ft);
    s_w[k * 8u + base + 1u] = w * (1.0 - fs) * ft;
    s_w[k * 8u + base + 2u] = w * fs * (1.0 - ft);
    s_w[k * 8u + base + 3u] = w * fs * ft;
    // sample (s, t) at theta = pi (s + 1/2) / R, phi = 2 pi t / R (shadow_field::sample_angles)
    float rad = step * float(c + 1u);
    float th0 = SFW_PI * (float(s0) + 0.5) / rf, th1 = SFW_PI * (float(s1) + 0.5) / rf;
    float ph0 = 2.0 * SFW_PI * float(t0) / rf, ph1 = 2.0 * SFW_PI * float(t1) / rf;
    s_spos[k * 8u + base + 0u] = vec4(centre + rad * sfw_polar(th0, ph0), 0.0);
    s_spos[k * 8u + base + 1u] = vec4(centre + rad * sfw_polar(th0, ph1), 0.0);
    s_spos[k * 8u + base + 2u] = vec4(centre + rad * sfw_polar(th1, ph0), 0.0);
    s_spos[k * 8u + base + 3u] = vec4(centre + rad * sfw_polar(th1, ph1), 0.0);
}

#include "sfw_cube.glsl"

float map_bit(uint word_off, uint texel) {
    return float((sfw_maps[word_off + (texel >> 5)] >> (texel & 31u)) & 1u);
}

// Visibility of occluder slot k at cube texel `texel` (its frame).
float occ_vis(uint k, uint texel) {
    float v = 0.0;
    for (uint t = 0u; t < 8u; t++) {
        float w = s_w[k * 8u + t];
        if (w > 0.0) v += w * map_bit(s_off[k * 8u + t], texel);
    }
    return v;
}

uint cube_texel(vec3 d) {
    uint face;
    vec2 xy;
    cube_coords(d, pc.n, face, xy);
    uvec2 ij = min(uvec2(xy), uvec2(pc.n - 1u));
    return face * pc.n * pc.n + ij.y * pc.n + ij.x;
}

// Visibility of occluder slot k toward world direction d: nearest texel (cube directions) or
// bilinear within the face (light directions); 1 outside its bounding cone.
float occ_vis_dir(uint k, vec3 d, bool bilinear) {
    vec4 cone = s_cone[k];
    if (dot(d, cone.xyz) < cone.w) return 1.0;
    SfwInst inst = sfw_inst[s_inst[k]];
    vec3 l = normalize(mat3(inst.world_to_local) * d);
    if (pc.reproject != 0u && cone.w > -1.0) {
        // Each tap's sample point looks at where the point's ray passes nearest the object's
        // centre (instead of along the same direction from a point up to a sample spacing
        // away): the neighbours agree on where the occluder is, so the interpolation blends
        // aligned maps instead of shifted copies. Only from outside the bounding sphere: from
        // inside (a ground plane's field over the objects standing on it) that nearest pass
        // can be the point itself, seen from samples on the far side of the occluder.
        vec3 pl = s_plocal[k].xyz;
        vec3 q = pl + max(dot(inst.center_step.xyz - pl, l), 0.0) * l;
        float v = 0.0;
        for (uint t = 0u; t < 8u; t++) {
            float w = s_w[k * 8u + t];
            if (!(w > 0.0)) continue;
            vec3 dt = q - s_spos[k * 8u + t].xyz;
            float len = length(dt);
            v += w * map_bit(s_off[k * 8u + t], cube_texel(len > 1e-12 ? dt / len : l));
        }
        return v;
    }
    uint face;
    vec2 xy;
    cube_coords(l, pc.n, face, xy);
    uint n = pc.n;
    uint base = face * n * n;
    if (!bilinear) {
        uvec2 ij = min(uvec2(xy), uvec2(n - 1u));
        return occ_vis(k, base + ij.y * n + ij.x);
    }
    vec2 c = clamp(xy - 0.5, vec2(0.0), vec2(float(n - 1u)));
    uvec2 i0 = min(uvec2(floor(c)), uvec2(n - 1u));
    uvec2 i1 = min(i0 + 1u, uvec2(n - 1u));
    vec2 f = c - vec2(i0);
    float a = mix(occ_vis(k, base + i0.y * n + i0.x), occ_vis(k, base + i0.y * n + i1.x), f.x);
    float b = mix(occ_vis(k, base + i1.y * n + i0.x), occ_vis(k, base + i1.y * n + i1.x), f.x);
    return mix(a, b, f.y);
}

void main() {
    ivec2 p = ivec2(gl_WorkGroupID.xy);
    ivec2 size = imageSize(hdr);
    uint lane = gl_LocalInvocationIndex;
    if (p.x >= size.x || p.y >= size.y) return;  // uniform over the workgroup
    vec4 uvm = texelFetch(gb_uv_mat, p, 0);
    if (uvm.w < 0.5) {
        if (lane == 0u) {
            vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
            vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
            vec3 dir = far_p.xyz / far_p.w - cam.eye.xyz;
            imageStore(hdr, p, vec4(env_background(dir), 1.0));
        }
        return;  // uniform: every invocation read the same texel
    }
    vec4 gp = texelFetch(gb_position, p, 0);
    vec3 pos = gp.xyz, ng = gb_geometric_normal(gp.w);
    vec4 en = texelFetch(gb_normal, p, 0);
    vec3 n = oct_decode(en.xy), tg = oct_decode(en.zw);
    uint self_inst = uint(uvm.w + 0.5) - 1u;
    MaterialData m = material_at(mats[uint(uvm.z)], uvm.xy, material_textures);
    int kind = int(m.albedo_kind.w + 0.5);
    vec3 v = normalize(cam.eye.xyz - pos);
    vec3 r = reflect(-v, n);
    float alpha = env_alpha(m);

    // The occluders (lane 0), nearest 16 by their centre.
    if (lane == 0u) {
        uint cnt = 0u;
        for (uint j = 0u; j < pc.n_inst; j++) {
            if (j == self_inst) continue;
            SfwInst inst = sfw_inst[j];
            uint nc = inst.info.y;
            if (nc == 0u || inst.info.z == 0u) continue;
            vec3 q = (inst.world_to_local * vec4(pos, 1.0)).xyz - inst.center_step.xyz;
            float len = length(q);
            float x = len / inst.center_step.w - 1.0;
            if (!(x <= float(nc - 1u))) continue;
            float d = distance(pos, inst.center_world.xyz);
            if (cnt == uint(SFW_MAX_OCC) && !(d < s_dist[cnt - 1u])) continue;
            uint k = min(cnt, uint(SFW_MAX_OCC) - 1u);
            while (k > 0u && s_dist[k - 1u] > d) {
                s_dist[k] = s_dist[k - 1u];
                s_inst[k] = s_inst[k - 1u];
                k--;
            }
            s_dist[k] = d;
            s_inst[k] = j;
            cnt = min(cnt + 1u, uint(SFW_MAX_OCC));
        }
        s_count = cnt;
    }
    barrier();
    // Taps per occluder (lanes 0 .. count - 1).
    uint count = s_count;
    if (lane < count) {
        SfwInst inst = sfw_inst[s_inst[lane]];
        vec3 q = (inst.world_to_local * vec4(pos, 1.0)).xyz - inst.center_step.xyz;
        float len = length(q);
        float theta = len > 0.0 ? acos(clamp(q.z / len, -1.0, 1.0)) : 0.0;
        float phi = len > 0.0 ? atan(q.y, q.x) : 0.0;
        if (phi < 0.0) phi += 2.0 * SFW_PI;
        uint nc = inst.info.y;
        float x = max(len / inst.center_step.w - 1.0, 0.0);
        uint c0 = min(uint(floor(x)), nc - 1u);
        uint c1 = min(c0 + 1u, nc - 1u);
        float w = c1 == c0 ? 0.0 : x - float(c0);
        shell_taps(inst.info.x + c0, c0, inst.center_step.xyz, inst.center_step.w, theta, phi, 1.0 - w, lane, 0u);
        shell_taps(inst.info.x + c1, c1, inst.center_step.xyz, inst.center_step.w, theta, phi, w, lane, 4u);
        s_plocal[lane] = vec4(q + inst.center_step.xyz, 0.0);
        vec3 to_c = inst.center_world.xyz - pos;
        float dc = length(to_c);
        float rc = inst.center_world.w;
        s_cone[lane] = dc > rc && dc > 0.0 ? vec4(to_c / dc, sqrt(max(1.0 - (rc / dc) * (rc / dc), 0.0))) : vec4(0.0, 0.0, 1.0, -2.0);
    }
    barrier();

    // This lane's share of the cube: diffuse L cos (shadowed, unshadowed) and the lobe's
    // environment light (shadowed, unshadowed, as luminance in w).
    uint total = 6u * pc.n * pc.n;
    // lobe sharpness: a GGX lobe of alpha as exp(s (r.w - 1)), s = 2 / alpha^2, capped so that
    // it spans a few cube pixels (else no pixel centre falls inside it)
    float pix = 2.0 / float(pc.n);
    float s_lobe = min(2.0 / max(alpha * alpha, 1e-6), 2.0 / (pix * pix));
    vec3 dsh = vec3(0.0), dun = vec3(0.0);
    float gsh = 0.0, gun = 0.0;
    for (uint i = lane; i < total; i += 64u) {
        vec3 d = sfw_dirs[i].xyz;
        vec3 L = sfw_dirs[total + i].rgb;
        float c = dot(n, d);
        float g = kind != 0 ? exp(s_lobe * (dot(r, d) - 1.0)) * dot(L, vec3(0.2126, 0.7152, 0.0722)) : 0.0;
        if (c <= 0.0 && g < 1e-12) continue;
        float vis = 1.0;
        for (uint k = 0u; k < count && vis > 0.0; k++) vis *= clamp(occ_vis_dir(k, d, false), 0.0, 1.0);
        if (c > 0.0) {
            dsh += L * c * vis;
            dun += L * c;
        }
        gsh += g * vis;
        gun += g;
    }
    s_red[lane] = vec4(dsh, 0.0);
    s_red[64u + lane] = vec4(dun, 0.0);
    s_red[128u + lane] = vec4(gsh, gun, 0.0, 0.0);
    barrier();
    for (uint stride = 32u; stride > 0u; stride >>= 1) {
        if (lane < stride) {
            s_red[lane] += s_red[lane + stride];
            s_red[64u + lane] += s_red[64u + lane + stride];
            s_red[128u + lane] += s_red[128u + lane + stride];
        }
        barrier();
    }
    if (lane != 0u) return;
    vec3 share_self = texelFetch(self_share, p, 0).rgb;
    vec4 lights_self = texelFetch(self_lights, p, 0);
    vec3 da = material_diffuse_albedo(m, dot(n, v));
    vec3 diffuse = da / PI * irr_ratio(n, s_red[0].rgb, s_red[64].rgb) * share_self;
    vec3 pk = pos + ng * 1e-3 * max(1.0, length(pos));
    for (uint k = 0u; k < pc.key_count; ++k)
        diffuse += da / PI * key_light_irradiance(key[2u * k], key[2u * k + 1u].rgb, pk, n, ng);
    vec3 color = diffuse;
    if (kind != 0) {
        vec2 gs = s_red[128].xy;
        float vis = gs.y > 1e-12 ? clamp(gs.x / gs.y, 0.0, 1.0) : 1.0;
        vec3 glossy = env_glossy(n, tg, v, m);
        if (pc.key_count > 0u) {
            // the key lights' reflections through their own rays, the rest along the reflection
            vec3 amp;
            SG spec = sg_specular_lobe(kind, n, v, max(dot(n, v), 1e-4), m.extra.x, env_roughness(m), m.spec_rough.rgb, amp);
            SG gj = sg_product(spec, sg_clamped_cosine(n));
            vec2 acc = vec2(0.0);
            for (uint k = 0u; k < pc.key_count; ++k)
                key_light_glossy_share(key[2u * k], key[2u * k + 1u].rgb, amp, gj, pk, ng, acc);
            vis = glossy_share(acc, dot(glossy, vec3(0.2126, 0.7152, 0.0722)), cone_rays_visibility(pk, reflect(-v, n), env_alpha(m), ng));
        }
        color += vis * glossy;
    }
    for (uint i = 0u; i < pc.light_count; ++i) {
        LightData l = lights[i];
        vec3 wi;
        float dist, ndl;
        vec3 e = light_incident(l, pos, n, ng, wi, dist, ndl);
        if (ndl <= 0.0) continue;
        vec3 f = light_brdf(wi, n, tg, v, m.albedo_kind.rgb, m);
        if (all(equal(f, vec3(0.0)))) continue;
        float vis;
        if (pc.traced != 0u) {
            vis = light_rays_visibility(l, pos + ng * 1e-3 * max(1.0, length(pos)));
        } else {
            vis = i < 4u ? clamp(lights_self[i], 0.0, 1.0) : 1.0;
            for (uint k = 0u; k < count && vis > 0.0; k++)
                if (s_dist[k] < dist) vis *= clamp(occ_vis_dir(k, wi, true), 0.0, 1.0);
        }
        color += vis * f * e * ndl;
    }
    imageStore(hdr, p, vec4(material_reflected(max(color, vec3(0.0)), n, v) + material_emission(m), 1.0));
}
