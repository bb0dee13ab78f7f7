// Integral spherical Gaussian (Iwasaki et al. 2012): the tabulated normalized ISG and the patch
// visibility integral with sphere blockers. f32 mirror of penumbra_math::isg (IsgTable::eval,
// visible_fraction). The including shader defines ISG_TABLE_BINDING and ISG_NODES_BINDING (set 0
// texel buffers: the IsgTable::to_gpu floats and the sphere BVH, root 0, see passes/src/isg)
// and ISG_MAX_SIDE (patches per side, <= 32); optionally ISG_TRIS_BINDING and
// ISG_TRI_NODES_BINDING (thin-shell triangles and their BVH, texel buffers too).
#ifndef PENUMBRA_ISG_GLSL
#define PENUMBRA_ISG_GLSL

#define ISG_HALF_PI 1.57079632679489662

struct IsgNode {
    vec4 sphere;  // xyz centre (world), w radius
    ivec4 info;   // x left child (-1 for a leaf), y right child, z sphere index, w unused
};

// Read through uniform texel buffers (R32G32B32A32_UINT views: on a CPU device one gather per
// texel where a storage-buffer read is a scalar load per lane and component): the table's floats
// four to a texel, a node in two texels.
layout(set = 0, binding = ISG_TABLE_BINDING) uniform usamplerBuffer isg_table;
layout(set = 0, binding = ISG_NODES_BINDING) uniform usamplerBuffer isg_nodes;
#define ISG_T(i) uintBitsToFloat(texelFetch(isg_table, int(i) >> 2)[int(i) & 3])
IsgNode isg_node_at(usamplerBuffer b, int i) {
    IsgNode nd;
    nd.sphere = uintBitsToFloat(texelFetch(b, 2 * i));
    nd.info = ivec4(texelFetch(b, 2 * i + 1));
    return nd;
}

// The invocation's choices (penumbra_math::isg::{IsgModel, PatchRule}), set by the including
// shader from its push constants before calling isg_visible:
// isg_paper_fit: the corners' normalized ISG by eq. 14's two sigmoids with the appendix
//   polynomials (their coefficients follow the table's data, IsgTable::to_gpu), not the table;
// isg_paper_rule: a sphere occludes every patch its cap overlaps (the paper's rule), not only
//   those whose centre it covers.
bool isg_paper_fit = false;
bool isg_paper_rule = false;

float isg_level_gamma(int l) {
    return pow(10.0, ISG_T(2) + float(l) / ISG_T(0));
}

float isg_lookup_level(int l, float th, float ph) {
    int n = int(ISG_T(1) + 0.5);
    int levels = int(ISG_T(3) + 0.5);
    float k = sqrt(isg_level_gamma(l)) + 0.5;
    float an = atan(k * ISG_HALF_PI);
    float vt = (atan(k * (clamp(th, 0.0, 3.14159265) - ISG_HALF_PI)) / an + 1.0) * 0.5 * float(n - 1);
    float vp = (atan(k * (clamp(ph, 0.0, 3.14159265) - ISG_HALF_PI)) / an + 1.0) * 0.5 * float(n - 1);
    int i = clamp(int(floor(vt)), 0, n - 2);
    int j = clamp(int(floor(vp)), 0, n - 2);
    float a = clamp(vt - float(i), 0.0, 1.0);
    float b = clamp(vp - float(j), 0.0, 1.0);
    int base = 4 + levels + l * n * n;
    float d00 = ISG_T(base + i * n + j);
    float d01 = ISG_T(base + i * n + j + 1);
    float d10 = ISG_T(base + (i + 1) * n + j);
    float d11 = ISG_T(base + (i + 1) * n + j + 1);
    return mix(mix(d00, d01, b), mix(d10, d11, b), a);
}

// Level position of a sharpness: (first level, weight of the next).
vec2 isg_level_pos(float gamma) {
    int levels = int(ISG_T(3) + 0.5);
    float x = clamp((log(max(gamma, 1e-2)) / log(10.0) - ISG_T(2)) * ISG_T(0), 0.0, float(levels - 1));
    float l0 = min(floor(x), float(max(levels - 2, 0)));
    return vec2(l0, clamp(x - l0, 0.0, 1.0));
}

float isg_sigmoid(float x) {
    return x >= 0.0 ? 1.0 / (1.0 + exp(-x)) : exp(x) / (1.0 + exp(x));
}

// The appendix's quartic k (0: g, 1: h) in gamma / 100, gamma clamped to the fit's 1..1e4.
float isg_paper_poly(int k, float gamma) {
    int levels = int(ISG_T(3) + 0.5), n = int(ISG_T(1) + 0.5);
    int c = 4 + levels + levels * n * n + 5 * k;
    float x = clamp(gamma, 1.0, 1e4) / 100.0;
    return (((ISG_T(c) * x + ISG_T(c + 1)) * x + ISG_T(c + 2)) * x + ISG_T(c + 3)) * x + ISG_T(c + 4);
}

// Normalized ISG S(theta, phi) / S(pi, pi), in [0, 1].
float isg_eval(float th, float ph, float gamma) {
    if (isg_paper_fit) {
        float g = max(gamma, 0.0);
        return isg_sigmoid(isg_paper_poly(0, g) * (th - ISG_HALF_PI)) * isg_sigmoid(isg_paper_poly(1, g) * (ph - ISG_HALF_PI));
    }
    vec2 lp = isg_level_pos(gamma);
    int l0 = int(lp.x);
    float g = max(gamma, 1e-2);
    float s0 = sqrt((g + 1.0) / (isg_level_gamma(l0) + 1.0));
    float s1 = sqrt((g + 1.0) / (isg_level_gamma(l0 + 1) + 1.0));
    float v0 = isg_lookup_level(l0, ISG_HALF_PI + (th - ISG_HALF_PI) * s0, ISG_HALF_PI + (ph - ISG_HALF_PI) * s0);
    float v1 = lp.y > 0.0 ? isg_lookup_level(l0 + 1, ISG_HALF_PI + (th - ISG_HALF_PI) * s1, ISG_HALF_PI + (ph - ISG_HALF_PI) * s1) : 0.0;
    return clamp(mix(v0, v1, lp.y), 0.0, 1.0);
}

// Limiting angle (half-width about the lobe axis) for the table's epsilon.
float isg_limit(float gamma) {
    vec2 lp = isg_level_pos(gamma);
    int l0 = int(lp.x);
    float a0 = ISG_T(4 + l0), a1 = ISG_T(4 + l0 + 1);
    // Interpolate the lobe width (1/angle scales like sqrt(gamma)) rather than the angle.
    float d = 1.0 / mix(1.0 / a0, 1.0 / a1, lp.y);
    return clamp(d, 1e-5, ISG_HALF_PI);
}

// Per-invocation patch mask of isg_visible (row i: bit j = patch (i, j) occluded), and the
// sines/cosines of the patch-centre angles (theta_i = phi_i for the same index), set once per
// isg_visible call.
uint isg_mask[ISG_MAX_SIDE];
float isg_sin_c[ISG_MAX_SIDE];
float isg_cos_c[ISG_MAX_SIDE];
// (cos, sin) of the patch step: the rotation from one patch centre angle to the next
vec2 isg_rot;

// (cos, sin) of the next patch centre angle after the one of cs.
vec2 isg_next_angle(vec2 cs) { return vec2(cs.x * isg_rot.x - cs.y * isg_rot.y, cs.y * isg_rot.x + cs.x * isg_rot.y); }

// Bits j0..=j1 of a row's mask (none when j1 < j0; 0 <= j0, j1 <= 31).
uint isg_bit_range(int j0, int j1) {
    if (j1 < j0) return 0u;
    uint hi = j1 >= 31 ? 0xffffffffu : ((1u << uint(j1 + 1)) - 1u);
    return hi & ~((1u << uint(j0)) - 1u);
}

// The cap's phi half-width at polar angle th (rho = |cl.xz|): pi when the whole circle of
// latitude is inside, -1 when none of it is (penumbra_math::isg's cap_half_width).
float isg_cap_half_width(float th, vec3 cl, float rho, float cos_psi) {
    float rhs = cos_psi - cos(th) * cl.y;
    float den = sin(th) * rho;
    if (den <= 1e-7) return rhs <= 0.0 ? 3.14159265 : -1.0;
    float q = rhs / den;
    if (q <= -1.0) return 3.14159265;
    return q <= 1.0 ? acos(q) : -1.0;
}

// The paper's rule (isg_paper_rule): marks every patch whose extent overlaps the cap (rows
// meeting theta_c +- psi; in each row the cap's phi range at its widest over the row, at the
// row's edges or nearest the cap's centre). Mirror of penumbra_math::isg's mark_cap_paper.
bool isg_mark_cap_paper(vec3 cl, float psi, float delta, float step_a, int side) {
    float cos_psi = cos(psi);
    float rho = length(cl.xz);
    float phc = atan(cl.z, cl.x);
    float phi0 = ISG_HALF_PI - delta;
    float thc = acos(clamp(cl.y, -1.0, 1.0));
    int r0 = max(int(floor((thc - psi - phi0) / step_a)), 0);
    int r1 = min(int(ceil((thc + psi - phi0) / step_a)) - 1, side - 1);
    bool any_occ = false;
    for (int i = r0; i <= r1; ++i) {
        float t0 = phi0 + step_a * float(i), t1 = phi0 + step_a * float(i + 1);
        float w = max(max(isg_cap_half_width(t0, cl, rho, cos_psi), isg_cap_half_width(t1, cl, rho, cos_psi)),
                      isg_cap_half_width(clamp(thc, t0, t1), cl, rho, cos_psi));
        if (w < 0.0) continue;
        uint bits = 0u;
        for (int k = -1; k <= 1; ++k) {
            float a = phc + 6.28318531 * float(k) - w;
            float b = phc + 6.28318531 * float(k) + w;
            int j0 = max(int(floor((a - phi0) / step_a)), 0);
            int j1 = min(int(ceil((b - phi0) / step_a)) - 1, side - 1);
            bits |= isg_bit_range(j0, j1);
        }
        isg_mask[i] |= bits;
        any_occ = any_occ || bits != 0u;
    }
    return any_occ;
}

// Marks the patches covered by the cap (world unit centre direction c, angular radius psi);
// true if any patch was marked.
bool isg_mark_cap(vec3 c, float psi, vec3 fx, vec3 fy, vec3 fz, float delta, float step_a, int side) {
    float cos_psi = cos(psi);
    vec3 cl = vec3(dot(c, fx), dot(c, fy), dot(c, fz));
    if (isg_paper_rule) return isg_mark_cap_paper(cl, psi, delta, step_a, side);
    float phi0 = ISG_HALF_PI - delta;
    bool any_occ = false;
    // Only rows whose centre angle theta_i is within psi of the cap centre's can meet it.
    float thc = acos(clamp(cl.y, -1.0, 1.0));
    int r0 = max(int(ceil((thc - psi - phi0) / step_a - 0.5)), 0);
    int r1 = min(int(floor((thc + psi - phi0) / step_a - 0.5)), side - 1);
    uint cols = side < 32 ? (1u << uint(side)) - 1u : 0xffffffffu;
    for (int i = r0; i <= r1; ++i) {
        // patch centre d in the cap: dot(d, c) = sin theta_i (cos phi_j cl.x + sin phi_j cl.z)
        // + cos theta_i cl.y >= cos psi, the row's patches tested with phi_j stepped by a
        // rotation (as isg_mark_triangle: cheaper than the row's range from an acos)
        uint cand = cols & ~isg_mask[i];
        if (cand == 0u) continue;
        float st = isg_sin_c[i], ct = isg_cos_c[i];
        float X = cl.x * st, Z = cl.z * st, Y = cl.y * ct - cos_psi;
        int j0 = findLSB(cand), j1 = findMSB(cand);
        vec2 cs = vec2(isg_cos_c[j0], isg_sin_c[j0]);
        uint bits = 0u;
        for (int j = j0; j <= j1; ++j) {
            if (X * cs.x + Z * cs.y + Y >= 0.0) bits |= 1u << uint(j);
            cs = isg_next_angle(cs);
        }
        bits &= cand;
        isg_mask[i] |= bits;
        any_occ = any_occ || bits != 0u;
    }
    return any_occ;
}

#ifdef ISG_TRIS_BINDING
// Thin-shell triangles (world space, 3 vec4 per triangle, xyz used) and their BVH of bounding
// spheres (IsgNode, info.z = triangle index).
layout(set = 0, binding = ISG_TRIS_BINDING) uniform usamplerBuffer isg_tris;
layout(set = 0, binding = ISG_TRI_NODES_BINDING) uniform usamplerBuffer isg_tri_nodes;
#define ISG_TRI(i) uintBitsToFloat(texelFetch(isg_tris, int(i)))

// Marks the patches whose centre direction, seen from p, passes through the triangle
// (projected triangle: the spherical triangle of the three vertex directions; candidates: the
// unmarked patches of the rows its bounding cap meets, then three plane-side tests per
// candidate patch). Triangles whose plane
// contains p and triangles entirely below the tangent plane are skipped.
bool isg_mark_triangle(int t, vec3 p, vec3 n, vec3 fx, vec3 fy, vec3 fz, float delta, float cone, float step_a, int side) {
    vec3 a = ISG_TRI(3 * t).xyz - p, b = ISG_TRI(3 * t + 1).xyz - p, c = ISG_TRI(3 * t + 2).xyz - p;
    if (max(dot(a, n), max(dot(b, n), dot(c, n))) <= 0.0) return false;
    float la = length(a), lb = length(b), lc = length(c);
    if (!(la > 0.0 && lb > 0.0 && lc > 0.0)) return false;
    vec3 nab = cross(a, b), nbc = cross(b, c), nca = cross(c, a);
    float det = dot(a, nbc);
    if (abs(det) <= 1e-7 * la * lb * lc) return false;  // p in the triangle's plane
    float s = det > 0.0 ? 1.0 : -1.0;
    vec3 ua = a / la, ub = b / lb, uc = c / lc;
    vec3 m = ua + ub + uc;
    float lm = length(m);
    if (!(lm > 1e-6)) return false;
    m /= lm;
    float cos_psi = min(dot(m, ua), min(dot(m, ub), dot(m, uc)));
    float psi = acos(clamp(cos_psi, -1.0, 1.0));
    if (acos(clamp(dot(m, fz), -1.0, 1.0)) - psi > cone) return false;
    vec3 cl = vec3(dot(m, fx), dot(m, fy), dot(m, fz));
    float phi0 = ISG_HALF_PI - delta;
    bool any_occ = false;
    // the edge planes' normals in the lobe's frame, facing inwards
    vec3 ex = s * vec3(dot(fx, nab), dot(fx, nbc), dot(fx, nca));
    vec3 ey = s * vec3(dot(fy, nab), dot(fy, nbc), dot(fy, nca));
    vec3 ez = s * vec3(dot(fz, nab), dot(fz, nbc), dot(fz, nca));
    // Candidates: the patches in the rows within psi of the bounding cap's centre angle (all
    // rows for a cap wider than a quarter sphere, not convex). Narrower column ranges (per row
    // from the cap: an acos each; per triangle from its azimuth range: an atan and an asin)
    // cost more than testing the row's patches (session 42).
    bool wide = cos_psi <= 0.02;
    float thc = acos(clamp(cl.y, -1.0, 1.0));
    int r0 = wide ? 0 : max(int(ceil((thc - psi - phi0) / step_a - 0.5)), 0);
    int r1 = wide ? side - 1 : min(int(floor((thc + psi - phi0) / step_a - 0.5)), side - 1);
    uint cols = side < 32 ? (1u << uint(side)) - 1u : 0xffffffffu;
    for (int i = r0; i <= r1; ++i) {
        uint cand = cols & ~isg_mask[i];
        if (cand == 0u) continue;
        // The patch centre d = (fx cos phi_j + fz sin phi_j) sin theta_i + fy cos theta_i is
        // inside when the three edge planes' dot products with it are >= 0: per edge
        // X cos phi_j + Z sin phi_j + Y, with phi_j stepped by a rotation from the row's first
        // candidate (no per-patch table reads: a lane's own index is a gather on a SIMD CPU;
        // session 42, hat_on_cloth's isg_shade 1.3-1.5 -> 0.96 s at 160x120).
        float st = isg_sin_c[i], ct = isg_cos_c[i];
        vec3 X = ex * st, Z = ez * st, Y = ey * ct;
        int j0 = findLSB(cand), j1 = findMSB(cand);
        vec2 cs = vec2(isg_cos_c[j0], isg_sin_c[j0]);
        uint bits = 0u;
        for (int j = j0; j <= j1; ++j) {
            vec3 f = X * cs.x + Z * cs.y + Y;
            if (min(f.x, min(f.y, f.z)) >= 0.0) bits |= 1u << uint(j);
            cs = isg_next_angle(cs);
        }
        bits &= cand;
        isg_mask[i] |= bits;
        any_occ = any_occ || bits != 0u;
    }
    return any_occ;
}
#endif

// True if the segment from p to p + dir * len (unit dir) meets an occluder: a leaf sphere of
// the sphere BVH (spheres containing p are skipped, as in isg_visible) or, with
// ISG_TRIS_BINDING, a thin-shell triangle. The shadow-ray test for local lights.
bool isg_segment_blocked(vec3 p, vec3 dir, float len, int node_count, int tri_node_count) {
#ifndef ISG_TRIS_BINDING
    tri_node_count = 0;
#endif
    int stack[32];
    int sp = 0;
    if (node_count > 0) stack[sp++] = 0;
    int guard = 0;
    while (sp > 0 && guard < 4096) {
        ++guard;
        int ni = stack[--sp];
        if (ni < 0 || ni >= node_count) continue;
        IsgNode node = isg_node_at(isg_nodes, ni);
        vec3 d = node.sphere.xyz - p;
        float r = node.sphere.w;
        if (!(r > 0.0)) continue;
        float t = clamp(dot(d, dir), 0.0, len);
        vec3 off = d - dir * t;
        if (dot(off, off) > r * r) continue;  // the segment misses the bounding sphere
        if (node.info.x >= 0) {
            if (sp < 31) {
                stack[sp++] = node.info.x;
                stack[sp++] = node.info.y;
            }
            continue;
        }
        if (dot(d, d) <= r * r * (1.0 + 2e-4)) continue;  // the receiver's own proxy
        return true;
    }
#ifdef ISG_TRIS_BINDING
    sp = 0;
    if (tri_node_count > 0) stack[sp++] = 0;
    guard = 0;
    while (sp > 0 && guard < 16384) {
        ++guard;
        int ni = stack[--sp];
        if (ni < 0 || ni >= tri_node_count) continue;
        IsgNode node = isg_node_at(isg_tri_nodes, ni);
        vec3 d = node.sphere.xyz - p;
        float r = node.sphere.w;
        if (!(r >= 0.0)) continue;
        float t = clamp(dot(d, dir), 0.0, len);
        vec3 off = d - dir * t;
        if (dot(off, off) > r * r) continue;
        if (node.info.x >= 0) {
            if (sp < 31) {
                stack[sp++] = node.info.x;
                stack[sp++] = node.info.y;
            }
            continue;
        }
        // Moller-Trumbore, hits strictly inside (0, len) beyond a relative epsilon.
        int tri = node.info.z;
        vec3 a = ISG_TRI(3 * tri).xyz, e1 = ISG_TRI(3 * tri + 1).xyz - a, e2 = ISG_TRI(3 * tri + 2).xyz - a;
        vec3 pv = cross(dir, e2);
        float det = dot(e1, pv);
        if (abs(det) < 1e-12) continue;
        float inv = 1.0 / det;
        vec3 tv = p - a;
        float u = dot(tv, pv) * inv;
        if (u < 0.0 || u > 1.0) continue;
        vec3 qv = cross(tv, e1);
        float v = dot(dir, qv) * inv;
        if (v < 0.0 || u + v > 1.0) continue;
        float th = dot(e2, qv) * inv;
        if (th > 1e-4 * len && th < len * (1.0 - 1e-4)) return true;
    }
#endif
    return false;
}

// Fraction of the hemisphere integral of the SG exp(gamma (dot(axis, w) - 1)) visible from p
// (normal n) through the sphere BVH (node_count nodes) and, with ISG_TRIS_BINDING, the
// thin-shell triangle BVH (tri_node_count nodes). side: patches per side (<= ISG_MAX_SIDE);
// lod: an inner node whose projected half-angle is below lod times the patch size is
// rasterized as one sphere. Spheres containing p are skipped (the receiver's own proxy);
// spheres entirely below the tangent plane are skipped. Mirror of
// penumbra_math::isg::visible_fraction_with_triangles.
float isg_visible(vec3 p, vec3 n, vec3 axis, float gamma, int node_count, int tri_node_count, int side, float lod) {
#ifndef ISG_TRIS_BINDING
    tri_node_count = 0;
#endif
    if (node_count <= 0 && tri_node_count <= 0) return 1.0;
    side = clamp(side, 1, ISG_MAX_SIDE);
    float delta = isg_limit(gamma);
    vec3 fz = axis;
    vec3 fx = normalize(abs(fz.x) < 0.9 ? cross(vec3(1.0, 0.0, 0.0), fz) : cross(vec3(0.0, 1.0, 0.0), fz));
    vec3 fy = cross(fz, fx);
    float cone = min(delta * 1.41421356, 3.14159265);
    float step_a = 2.0 * delta / float(side);
    isg_rot = vec2(cos(step_a), sin(step_a));
    for (int i = 0; i < side; ++i) {
        isg_mask[i] = 0u;
        float t = ISG_HALF_PI - delta + step_a * (float(i) + 0.5);
        isg_sin_c[i] = sin(t);
        isg_cos_c[i] = cos(t);
    }
    bool any_occ = false;
    int stack[32];
    int sp = 0;
    if (node_count > 0) stack[sp++] = 0;
    int guard = 0;
    while (sp > 0 && guard < 4096) {
        ++guard;
        int ni = stack[--sp];
        if (ni < 0 || ni >= node_count) continue;
        IsgNode node = isg_node_at(isg_nodes, ni);
        vec3 d = node.sphere.xyz - p;
        float r = node.sphere.w;
        if (!(r > 0.0)) continue;
        if (dot(d, n) < -r) continue;  // below the tangent plane: nothing in it shadows p
        float dist = length(d);
        bool leaf = node.info.x < 0;
        bool contains = dist <= r * (1.0 + 1e-4);
        if (contains) {
            if (!leaf && sp < 31) {
                stack[sp++] = node.info.x;
                stack[sp++] = node.info.y;
            }
            continue;
        }
        vec3 c = d / dist;
        float psi = asin(clamp(r / dist, 0.0, 1.0));
        float ang = acos(clamp(dot(c, fz), -1.0, 1.0));
        if (ang - psi > cone) continue;  // cone-vs-sphere culling
        if (!leaf && psi > lod * step_a && sp < 31) {
            stack[sp++] = node.info.x;
            stack[sp++] = node.info.y;
            continue;
        }
        any_occ = isg_mark_cap(c, psi, fx, fy, fz, delta, step_a, side) || any_occ;
    }
#ifdef ISG_TRIS_BINDING
    // Thin shells: bounding spheres culled against the cone and the tangent plane, always
    // descended to the triangles (a shell has no interior to rasterize as a sphere).
    sp = 0;
    if (tri_node_count > 0) stack[sp++] = 0;
    guard = 0;
    while (sp > 0 && guard < 16384) {
        ++guard;
        int ni = stack[--sp];
        if (ni < 0 || ni >= tri_node_count) continue;
        IsgNode node = isg_node_at(isg_tri_nodes, ni);
        vec3 d = node.sphere.xyz - p;
        float r = node.sphere.w;
        if (!(r >= 0.0)) continue;
        if (dot(d, n) < -r) continue;
        float dist = length(d);
        if (dist > r) {
            float psi = asin(clamp(r / dist, 0.0, 1.0));
            if (acos(clamp(dot(d / dist, fz), -1.0, 1.0)) - psi > cone) continue;
        }
        if (node.info.x < 0) {
            any_occ = isg_mark_triangle(node.info.z, p, n, fx, fy, fz, delta, cone, step_a, side) || any_occ;
        } else if (sp < 31) {
            stack[sp++] = node.info.x;
            stack[sp++] = node.info.y;
        }
    }
#endif
    if (!any_occ) return 1.0;
    float occ = 0.0;
    for (int i = 0; i < side; ++i) {
        uint bits = isg_mask[i];
        if (bits == 0u) continue;
        float t0 = i == 0 ? 0.0 : ISG_HALF_PI - delta + step_a * float(i);
        float t1 = i == side - 1 ? 3.14159265 : ISG_HALF_PI - delta + step_a * float(i + 1);
        int j = 0;
        while (j < side) {
            if ((bits & (1u << uint(j))) == 0u) { ++j; continue; }
            int j0 = j;
            while (j < side && (bits & (1u << uint(j))) != 0u) ++j;
            float p0 = j0 == 0 ? 0.0 : ISG_HALF_PI - delta + step_a * float(j0);
            float p1 = j == side ? 3.14159265 : ISG_HALF_PI - delta + step_a * float(j);
            occ += max(isg_eval(t1, p1, gamma) - isg_eval(t0, p1, gamma) - isg_eval(t1, p0, gamma) + isg_eval(t0, p0, gamma), 0.0);
        }
    }
    return clamp(1.0 - occ, 0.0, 1.0);
}

#endif
