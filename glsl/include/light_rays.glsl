// Local lights' shadows by shadow rays through the frame's kd-tree: the unoccluded fraction of
// light l seen from p, a point already offset from its surface. Point and spot lights: one ray
// (a hard shadow); sphere lights: lights.glsl's LIGHT_DISK_POINTS targets on the disk facing p.
// The includer includes lights.glsl and kdtree.glsl (with its KD_* accessors) first. Used by vv
// and the shadow fields (`light_shadows = traced`), whose own occluder representations carry no
// depth or only order-4 visibility toward a light.
#ifndef PENUMBRA_LIGHT_RAYS_GLSL
#define PENUMBRA_LIGHT_RAYS_GLSL
#include "sg.glsl"
#ifndef CONE_STRATIFIED
#define CONE_STRATIFIED false
#endif

float light_rays_visibility(LightData l, vec3 p) {
    vec3 to_light = light_vector(l, p);
    float radius = int(l.pos_kind.w + 0.5) == 2 ? l.extra.x : 0.0;
    int taps = radius > 0.0 ? LIGHT_DISK_POINTS : 1;
    float vis = 0.0, cnt = 0.0;
    for (int i = 0; i < taps; ++i) {
        if (disk_settled(i, vis, cnt)) break;
        cnt += 1.0;
        vec3 q = light_disk_target(to_light, radius, disk_ray(i));
        float len = length(q);
        if (!(len > 0.0)) {
            vis += 1.0;
            continue;
        }
        vis += kd_trace(p, q / len, 0.0, len * (1.0 - 1e-4), true).t >= 0.0 ? 0.0 : 1.0;
    }
    return vis / cnt;
}

// The unoccluded share of a cone of directions about unit `axis`: 9 rays through the kd-tree
// from p (a point already offset from its surface) in lights.glsl's disk pattern at angular
// radius `radius` (its tangent), rays under the plane of geometric normal ng left out. Also the
// glossy lobe's visibility about the reflection at radius GGX alpha where the shadow fields
// split off key lights (whose sharp reflections their coarse visibility would leave unblocked).
float cone_rays_visibility(vec3 p, vec3 axis, float radius, vec3 ng) {
    float vis = 0.0, cnt = 0.0;
    for (int i = 0; i < LIGHT_DISK_POINTS; ++i) {
        if (disk_settled(i, vis, cnt)) break;
        vec3 d = normalize(light_disk_target(axis, radius, disk_ray(i)));
        if (dot(d, ng) <= 0.0) continue;
        cnt += 1.0;
        vis += kd_trace(p, d, 0.0, 1e30, true).t >= 0.0 ? 0.0 : 1.0;
    }
    return cnt > 0.0 ? vis / cnt : 1.0;
}

// The direction of ray j (lights.glsl's disk order) of the uniform cone of unit `axis` and
// angular radius `radius` (its tangent) seen from point p. Fixed (CONE_STRATIFIED false, the
// default): lights.glsl's pattern, the same in every pixel. Stratified: the disk cut into 9 cells
// of equal area (the centre disk to radius / 3, whose ray is the axis; a ring of 4 quarter sectors
// to radius sqrt(5) / 3; an outer ring of 4 sectors), each ray at a point of its own cell drawn by
// a hash of p's bits, so that neighbouring pixels sample different points of their cells: a key
// light's penumbra comes out as grain around the disk's integral instead of the fixed pattern's
// flat bands (falling at 640x480: a hexagonal umbra ringed by steps), at more error against a
// reference (the grain adds to its noise). The includer may define CONE_STRATIFIED (a bool).
// 32 hashed bits of point p's float bits and ray number j: a per-point draw of ray j.
uint cone_hash(vec3 p, uint j) {
    uvec3 b = floatBitsToUint(p);
    uint h = b.x * 0x9E3779B1u ^ b.y * 0x85EBCA77u ^ b.z * 0xC2B2AE3Du ^ j * 0x27D4EB2Fu;
    h ^= h >> 15u; h *= 0x2C1B3C6Du; h ^= h >> 12u; h *= 0x297A2D39u; h ^= h >> 15u;
    return h;
}

vec3 cone_cell_dir(vec3 p, vec3 axis, float radius, int j) {
    if (!CONE_STRATIFIED) return normalize(light_disk_target(axis, radius, j));
    vec3 w = normalize(axis);
    if (j == 0) return w;
    uint h = cone_hash(p, uint(j));
    float u = float(h & 0xFFFFu) / 65536.0, v = float(h >> 16u) / 65536.0;
    // lights.glsl's rays 1-4: the inner ring at 0, 90, 180, 270 degrees; 5-8 the outer at 45 + k 90
    bool inner = j <= 4;
    float a = 1.5707963 * (float(j - 1) + (inner ? 0.0 : 0.5) + (u - 0.5));
    float r = radius * sqrt(inner ? (1.0 + 4.0 * v) / 9.0 : (5.0 + 4.0 * v) / 9.0);
    return normalize(w + light_disk_offset(w, a) * r);
}

// Rays toward a key light as a mask: bit j set where ray j (above the plane of ng) is
// unoccluded, bit 16 + j where ray j was traced (above the plane; the inner ring only in a
// penumbra), in cone_cell_dir's directions (fixed or stratified). avs traces a key light's rays once for its
// diffuse light (cone_mask_fraction) and for a glossy lobe nearly flat over the light
// (cone_mask_weighted).
// `hits` adds the blocked rays' hit distances (x) and their count (y): where the occluders are.
uint cone_rays_mask(vec3 p, vec3 axis, float radius, vec3 ng, inout vec2 hits) {
    uint m = 0u;
    for (int i = 0; i < LIGHT_DISK_POINTS; ++i) {
        if (disk_settled(i, float(bitCount(m & 0xFFFFu)), float(bitCount(m >> 16u)))) break;
        int j = disk_ray(i);
        vec3 d = cone_cell_dir(p, axis, radius, j);
        if (dot(d, ng) <= 0.0) continue;
        m |= 1u << uint(16 + j);
        // near children first: the blocked rays' distances say where the occluders are
        float t = kd_trace_order(p, d, 0.0, 1e30, true, false).t;
        if (t < 0.0) m |= 1u << uint(j); else hits += vec2(t, 1.0);
    }
    return m;
}

// cone_rays_visibility's value from cone_rays_mask's mask.
float cone_mask_fraction(uint m) {
    uint traced = bitCount(m >> 16u);
    return traced > 0u ? float(bitCount(m & 0xFFFFu)) / float(traced) : 1.0;
}

// The unoccluded share of the light of a uniform cone (cone_rays_mask's point, axis and radius)
// seen through lobe g: the cone's rays weighted by g at their directions (relative to the largest
// weight, so that a sharp lobe far from every ray does not underflow), the estimate of
// int_cone G V / int_cone G with the rays as samples of the cone.
float cone_mask_weighted(uint m, vec3 p, vec3 axis, float radius, SG g) {
    float best = -2.0;
    for (int j = 0; j < LIGHT_DISK_POINTS; ++j) {
        if ((m & (1u << uint(16 + j))) == 0u) continue;
        best = max(best, dot(g.axis, cone_cell_dir(p, axis, radius, j)));
    }
    if (best < -1.5) return 1.0;
    float num = 0.0, den = 0.0;
    for (int j = 0; j < LIGHT_DISK_POINTS; ++j) {
        if ((m & (1u << uint(16 + j))) == 0u) continue;
        float w = exp(g.lambda * (dot(g.axis, cone_cell_dir(p, axis, radius, j)) - best));
        den += w;
        if ((m & (1u << uint(j))) != 0u) num += w;
    }
    return den > 0.0 ? num / den : cone_mask_fraction(m);
}

// Irradiance at a point of normal n (offset point p, geometric normal ng) from one of the
// environment's key lights split off its map (penumbra_math::envmap::split_lights; axis_lambda:
// world axis + sharpness, mu: rgb amplitude): the lobe's SG-cosine integral times the unoccluded
// share of its cone (cone_rays_visibility at the angular radius 2 / sqrt(lambda) of the uniform
// disk whose mean cosine the lobe matches). The shadow fields' `key_lights`.
vec3 key_light_irradiance(vec4 axis_lambda, vec3 mu, vec3 p, vec3 n, vec3 ng) {
    SG g = sg_make(axis_lambda.xyz, axis_lambda.w, 1.0);
    vec3 e = mu * max(sg_cosine_integral(g, n), 0.0);
    if (max(e.r, max(e.g, e.b)) <= 0.0) return vec3(0.0);
    return e * cone_rays_visibility(p, g.axis, 2.0 / sqrt(max(g.lambda, 1e-4)), ng);
}

// The visibility of key light `l` (an SG light of amplitude 1) in the glossy lobe `gj`: rays in
// the cone of the two lobes' product (where the light is, not where the mirror direction is).
float key_light_lobe_visibility(SG l, SG gj, vec3 p, vec3 ng) {
    SG pr = sg_product(l, gj);
    return cone_rays_visibility(p, pr.axis, 2.0 / sqrt(max(pr.lambda, 1e-4)), ng);
}

// The glossy term's visibility where the environment's key lights were split off its map: each
// key light's part of the glossy term (its SG light in the glossy lobe `gj`, the BRDF's specular
// SG times the cosine, times the lobe's amplitude `amp`) is seen through rays in the cone of the
// two lobes' product, the rest of the map's part (the glossy term's luminance less the key
// lights', at least 0) as the technique sees it, and the shares are weighted by their light:
// sum_k e_k V_k / sum_k e_k. A sharp key light's reflection is then occluded where the light is,
// not where the mirror direction is (turning_light: the studio's key light behind the bunny,
// reflected by the glossy floor in front of it). Per key light (axis + lambda, rgb amplitude),
// adding (e V, e) to `acc`:
void key_light_glossy_share(vec4 axis_lambda, vec3 mu, vec3 amp, SG gj, vec3 p, vec3 ng, inout vec2 acc) {
    SG l = sg_make(axis_lambda.xyz, axis_lambda.w, 1.0);
    float e = dot(mu * amp, vec3(0.2126, 0.7152, 0.0722)) * sg_inner_product(l, gj);
    if (!(e > 0.0)) return;
    acc += vec2(e * key_light_lobe_visibility(l, gj, p, ng), e);
}

// ... then the visible share of the whole glossy term (luminance `total`), the rest seen as
// `rest_vis`.
float glossy_share(vec2 acc, float total, float rest_vis) {
    float rest = max(total - acc.y, 0.0);
    float den = acc.y + rest;
    return den > 0.0 ? clamp((acc.x + rest * rest_vis) / den, 0.0, 1.0) : rest_vis;
}

#endif
