// kd-tree layout and traversal shared by the tracer (trace.comp) and techniques.
//
// Before including, declare the tree's buffers with these names (any binding numbers):
//   uniform usamplerBuffer kd_tris    3 texels per triangle (world-space v0, v1, v2 as float
//                                     bits; v0.w = 1.0: casts no shadow, skipped by any-hit queries)
//   uniform usamplerBuffer kd_nodes   node 0 is the root
//   uniform usamplerBuffer kd_refs    triangle indices of the leaves, four per texel
//   readonly buffer { uint kd_hdr[]; } counters; scene box at KD_HDR_BOX (6 floats as bits)
// and define KD_HDR(i) (the accessors KD_TRI(i), KD_NODE(i), KD_REF(i) default to the texel
// buffers above). The tree is read through uniform texel buffers (passes bind them with
// Bind::TexelBuffer): on a CPU device (llvmpipe) a texel fetch at a per-invocation index is one
// gather of 16-byte texels where a storage-buffer read is a bounds-checked scalar load per lane
// and component; the BVH walk's rays ran 1.2-1.9x faster for it (session 41).
#ifndef KD_TRI
#define KD_TRI(i) uintBitsToFloat(texelFetch(kd_tris, int(i)))
#endif
#ifndef KD_NODE
#define KD_NODE(i) texelFetch(kd_nodes, int(i))
#endif
#ifndef KD_REF
#define KD_REF(i) (texelFetch(kd_refs, int((i) >> 2u))[(i) & 3u])
#endif
//
// Node (uvec4): y < 3: interior, x = split (float bits), y = axis, z = left child (right = z + 1);
//               y == 3: leaf, z = first ref, w = ref count; y == 4: pending (build only).
// The same buffers may hold a threaded BVH instead (header word KD_HDR_STRUCTURE = 1, built on
// the host: passes::kdtree::Structure::Bvh): node i is KD_NODE(2i) = (lo.xyz as float bits,
// miss link: the next node after its subtree, 0xffffffff ends), KD_NODE(2i + 1) = (hi.xyz,
// leaf info: 0 interior, whose first child is node i + 1, else count << 24 | first triangle);
// header word KD_HDR_BVH_LAYOUTS = 7: seven such trees one after the other, the same tree in
// seven depth-first orders: six per axis and sign (the nearer child first), a ray walking the one
// of its direction's largest component, and one for any-hit rays (the child likelier to stop a
// ray per node it costs first: passes::kdtree's any-hit order); 1: the first order alone;
// and the leaves' triangles are copied in leaf order after the nodes (from KD_NODE(base), base
// = header word KD_HDR_BVH_TRIS), 3 uvec4 each (v0, v1, v2 as float bits; v0.w the triangle's
// index | 1 << 31 if it casts no shadow).
#ifndef PENUMBRA_KDTREE_GLSL
#define PENUMBRA_KDTREE_GLSL

#define KD_HDR_BOX 8u
#define KD_HDR_STRUCTURE 7u
#define KD_HDR_BVH_TRIS 65u
#define KD_HDR_BVH_LAYOUTS 66u
#define KD_BVH_END 0xffffffffu
#define KD_LEAF 3u
#define KD_PENDING 4u
// Short stack (Horn et al. 2007) of 6 entries held in registers (a shift register: push moves
// every entry down and drops the oldest, pop moves them up; no dynamically indexed arrays, which
// a SIMD CPU driver would spill to memory); when it runs dry after a drop the ray restarts from
// the root past the last cell it finished.
#define KD_SHORT_STACK 6
// Guard against pathological inputs (NaN rays): give up after this many leaf visits.
#define KD_MAX_LEAVES 65536u
// The BVH walk's guard: node visits per ray.
#define KD_BVH_MAX_STEPS 1048576u

struct KdHit {
    float t;     // < 0: no hit
    float b1;    // barycentrics of v1 and v2
    float b2;
    uint tri;
};

// Watertight ray/triangle test (Woop, Benthin and Wald 2013). The per-ray permutation and shear
// are folded into three rows (one-hot minus shear), so the per-triangle work is dot products
// instead of dynamically indexed components: dot(row, A) = A[kx] - Sx A[kz] exactly (the other
// products are zero).
struct KdRayW {
    vec3 r0;     // e_kx - Sx e_kz
    vec3 r1;     // e_ky - Sy e_kz
    vec3 r2;     // Sz e_kz
};

KdRayW kd_ray_setup(vec3 d) {
    vec3 ad = abs(d);
    int kz = ad.x > ad.y ? (ad.x > ad.z ? 0 : 2) : (ad.y > ad.z ? 1 : 2);
    int kx = (kz + 1) % 3;
    int ky = (kx + 1) % 3;
    if (d[kz] < 0.0) { int tmp = kx; kx = ky; ky = tmp; }
    vec3 ex = vec3(0.0), ey = vec3(0.0), ez = vec3(0.0);
    ex[kx] = 1.0; ey[ky] = 1.0; ez[kz] = 1.0;
    float sx = d[kx] / d[kz], sy = d[ky] / d[kz], sz = 1.0 / d[kz];
    KdRayW r;
    r.r0 = ex - sx * ez;
    r.r1 = ey - sy * ez;
    r.r2 = sz * ez;
    return r;
}

// Returns true and t, b1, b2 when the ray hits the triangle with tmin <= t <= tmax.
bool kd_intersect(KdRayW r, vec3 o, vec3 p0, vec3 p1, vec3 p2, float tmin, float tmax,
                  out float t, out float b1, out float b2) {
    vec3 A = p0 - o, B = p1 - o, C = p2 - o;
    float Ax = dot(r.r0, A), Ay = dot(r.r1, A);
    float Bx = dot(r.r0, B), By = dot(r.r1, B);
    float Cx = dot(r.r0, C), Cy = dot(r.r1, C);
    float U = Cx * By - Cy * Bx;
    float V = Ax * Cy - Ay * Cx;
    float W = Bx * Ay - By * Ax;
    // (The paper's double-precision fallback for U, V or W == 0 is left out: float64 is an
    // optional device feature.)
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
    float det = U + V + W;
    if (det == 0.0) return false;
    float Az = dot(r.r2, A), Bz = dot(r.r2, B), Cz = dot(r.r2, C);
    float T = U * Az + V * Bz + W * Cz;
    if (det < 0.0) { T = -T; det = -det; U = -U; V = -V; W = -W; }
    if (T < tmin * det || T > tmax * det) return false;
    float inv = 1.0 / det;
    t = T * inv;
    b1 = V * inv;
    b2 = W * inv;
    return true;
}

vec3 kd_box_lo() { return vec3(uintBitsToFloat(KD_HDR(KD_HDR_BOX)), uintBitsToFloat(KD_HDR(KD_HDR_BOX + 1u)), uintBitsToFloat(KD_HDR(KD_HDR_BOX + 2u))); }
vec3 kd_box_hi() { return vec3(uintBitsToFloat(KD_HDR(KD_HDR_BOX + 3u)), uintBitsToFloat(KD_HDR(KD_HDR_BOX + 4u)), uintBitsToFloat(KD_HDR(KD_HDR_BOX + 5u))); }

// The threaded BVH's walk of o + t d over [t_enter, t_exit] (inside the scene box): no stack,
// each node's box tested once; any_hit stops at the first hit, closest-hit shrinks the range.
// occlusion_order (any_hit only, with the seventh layout): the children in the order likelier to
// stop the ray per node visited (kdtree.rs), else the nearer child first along the direction's
// largest component (a hit found early is then likely a near one).
KdHit kd_trace_bvh(KdRayW rw, vec3 o, vec3 d, float t_enter, float t_exit, float tmin, bool any_hit, bool occlusion_order) {
    KdHit h;
    h.t = -1.0; h.b1 = 0.0; h.b2 = 0.0; h.tri = 0xffffffffu;
    // a zero component's reciprocal made finite: its slab then spans the whole line or none
    vec3 dd = mix(d, mix(vec3(-1e-30), vec3(1e-30), greaterThanEqual(d, vec3(0.0))), lessThan(abs(d), vec3(1e-30)));
    vec3 inv = 1.0 / dd;
    float best = t_exit;
    uint node = 0u;
    uint base = KD_HDR(KD_HDR_BVH_TRIS);
    // the order of the direction's largest component and its sign, when the buffer holds all 7
    uint layouts = KD_HDR(KD_HDR_BVH_LAYOUTS);
    vec3 ad = abs(d);
    uint layout_k = ad.x >= ad.y && ad.x >= ad.z ? (d.x < 0.0 ? 1u : 0u) : (ad.y >= ad.z ? (d.y < 0.0 ? 3u : 2u) : (d.z < 0.0 ? 5u : 4u));
    if (any_hit && occlusion_order && layouts == 7u) layout_k = 6u;
    uint off = layouts == 7u ? layout_k * (base / 7u) : 0u;
    uint steps = 0u;
    while (node != KD_BVH_END && steps < KD_BVH_MAX_STEPS) {
        // Walk interior nodes until this ray enters a leaf's box, then test the leaf's triangles
        // ("while-while", Aila and Laine 2009): on a SIMD device the lanes that found a leaf
        // wait for the others, so the triangle loop runs with most lanes busy instead of
        // starting in nearly every node step for the few lanes in a leaf.
        uint leaf = 0u;
        while (node != KD_BVH_END && steps < KD_BVH_MAX_STEPS) {
            steps++;
            uvec4 a = KD_NODE(off + 2u * node), b = KD_NODE(off + 2u * node + 1u);
            vec3 t0 = (uintBitsToFloat(a.xyz) - o) * inv, t1 = (uintBitsToFloat(b.xyz) - o) * inv;
            vec3 tn = min(t0, t1), tf = max(t0, t1);
            float enter = max(max(tn.x, tn.y), max(tn.z, t_enter));
            float exit = min(min(tf.x, tf.y), min(tf.z, best));
            if (!(enter <= exit)) { node = a.w; continue; }
            if (b.w == 0u) { node++; continue; }
            leaf = b.w;
            node = a.w;
            break;
        }
        uint first = leaf & 0xffffffu, cnt = leaf >> 24u;
        for (uint j = 0u; j < cnt; j++) {
            uint r = base + 3u * (first + j);
            uvec4 q0 = KD_NODE(r);
            uint ti = q0.w;
            if (any_hit && ti >= 0x80000000u) continue; // casts no shadow
            float t, b1, b2;
            if (kd_intersect(rw, o, uintBitsToFloat(q0.xyz), uintBitsToFloat(KD_NODE(r + 1u).xyz), uintBitsToFloat(KD_NODE(r + 2u).xyz), tmin, best, t, b1, b2)) {
                best = t; h.t = t; h.b1 = b1; h.b2 = b2; h.tri = ti & 0x7fffffffu;
                if (any_hit) return h;
            }
        }
    }
    return h;
}

// Traces o + t d for t in [tmin, tmax]. any_hit: stop at the first hit found (visibility);
// occlusion_order: with any_hit, walk the threaded BVH in the order that finds some hit soonest
// (its t is then any occluder's), else near children first (its t likelier the nearest's).
KdHit kd_trace_order(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, bool occlusion_order) {
    KdHit h;
    h.t = -1.0; h.b1 = 0.0; h.b2 = 0.0; h.tri = 0xffffffffu;
    if (!(tmax >= tmin) || any(isnan(o)) || any(isnan(d)) || d == vec3(0.0)) return h;
    vec3 lo = kd_box_lo(), hi = kd_box_hi();
    if (lo.x > hi.x) return h; // empty tree
    vec3 inv = 1.0 / d;
    float t_enter = tmin, t_exit = tmax;
    for (int a = 0; a < 3; a++) {
        if (d[a] == 0.0) {
            if (o[a] < lo[a] || o[a] > hi[a]) return h;
        } else {
            float ta = (lo[a] - o[a]) * inv[a], tb = (hi[a] - o[a]) * inv[a];
            t_enter = max(t_enter, min(ta, tb));
            t_exit = min(t_exit, max(ta, tb));
        }
    }
    if (t_enter > t_exit) return h;
    KdRayW rw = kd_ray_setup(d);
    if (KD_HDR(KD_HDR_STRUCTURE) == 1u) return kd_trace_bvh(rw, o, d, t_enter, t_exit, tmin, any_hit, occlusion_order);

    // entry i: node s<i>n, interval s<i>t (tmin, tmax); s0 is the top
    uint s0n = 0u, s1n = 0u, s2n = 0u, s3n = 0u, s4n = 0u, s5n = 0u;
    vec2 s0t = vec2(0.0), s1t = vec2(0.0), s2t = vec2(0.0), s3t = vec2(0.0), s4t = vec2(0.0), s5t = vec2(0.0);
    int depth = 0;     // valid entries (<= KD_SHORT_STACK)
    bool dropped = false;
    float best = tmax;
    float g_min = t_enter;
    uint leaves = 0u;
    uint node = 0u;
    float cmin = t_enter, cmax = t_exit;
    while (true) {
        uvec4 nd = KD_NODE(node);
        if (nd.y < 3u) {
            uint axis = nd.y;
            float split = uintBitsToFloat(nd.x);
            float oa = o[axis], da = d[axis];
            bool below = oa < split || (oa == split && da <= 0.0);
            uint first = below ? nd.z : nd.z + 1u;
            uint second = below ? nd.z + 1u : nd.z;
            if (da == 0.0) { node = first; continue; }
            float ts = (split - oa) * inv[axis];
            if (ts > cmax || ts <= 0.0) {
                node = first;
            } else if (ts < cmin) {
                node = second;
            } else {
                if (depth == KD_SHORT_STACK) dropped = true; else depth++;
                s5n = s4n; s5t = s4t; s4n = s3n; s4t = s3t; s3n = s2n; s3t = s2t;
                s2n = s1n; s2t = s1t; s1n = s0n; s1t = s0t;
                s0n = second; s0t = vec2(ts, cmax);
                node = first;
                cmax = ts;
            }
            continue;
        }
        // leaf
        leaves++;
        uint off = nd.z, cnt = (nd.y == KD_LEAF) ? nd.w : 0u;
        for (uint j = 0u; j < cnt; j++) {
            uint ti = KD_REF(off + j);
            vec4 v0 = KD_TRI(3u * ti);
            if (any_hit && v0.w != 0.0) continue; // casts no shadow
            float t, b1, b2;
            if (kd_intersect(rw, o, v0.xyz, KD_TRI(3u * ti + 1u).xyz, KD_TRI(3u * ti + 2u).xyz, tmin, best, t, b1, b2)) {
                best = t; h.t = t; h.b1 = b1; h.b2 = b2; h.tri = ti;
                if (any_hit) return h;
            }
        }
        if (h.t >= 0.0 && best <= cmax) return h;
        if (leaves >= KD_MAX_LEAVES) return h;
        if (depth > 0) {
            depth--;
            node = s0n; cmin = s0t.x; cmax = s0t.y;
            s0n = s1n; s0t = s1t; s1n = s2n; s1t = s2t; s2n = s3n; s2t = s3t;
            s3n = s4n; s3t = s4t; s4n = s5n; s4t = s5t;
            if (h.t >= 0.0 && cmin > best) return h;
        } else if (dropped && cmax < t_exit) {
            // restart from the root past the finished cells
            g_min = max(g_min, cmax);
            dropped = false;
            node = 0u; cmin = g_min; cmax = t_exit;
        } else {
            return h;
        }
    }
    return h;
}

// Traces o + t d for t in [tmin, tmax]; any_hit: stop at the first hit found, in the order
// that finds one soonest (visibility: only whether t >= 0 means anything).
KdHit kd_trace(vec3 o, vec3 d, float tmin, float tmax, bool any_hit) {
    return kd_trace_order(o, d, tmin, tmax, any_hit, true);
}

#endif
