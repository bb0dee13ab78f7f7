// Shared by the kd-tree build kernels (kdtree_build.comp, kdtree_small.comp), which declare the
// triangles as `tris` before including it: the references' bounds and assignment to children,
// and the large-node lists in the header buffer `ctr` (see passes/src/kdtree.rs). Level L's nodes with more than
// small_max references are listed (parity L & 1) by their parents, so the workgroup-per-node
// kernel visits only them; an overflowing list makes that level scan all its nodes.
#ifndef PENUMBRA_KDTREE_BUILD_GLSL
#define PENUMBRA_KDTREE_BUILD_GLSL
#define KD_LIST_COUNT 112u
#define KD_LIST_OVERFLOW 114u
#define KD_LIST_BASE 128u
#define KD_LIST_CAP 4096u

// Whether the triangle (a, b, c) and the box [lo, hi] overlap: the separating axis test of
// Akenine-Moller (2001), the box's three face normals, the triangle's normal and the nine
// products of their edges. Conservative: a degenerate triangle or NaN coordinates separate on
// no axis (every comparison false), so they count as overlapping.
bool kd_separated(vec3 axis, vec3 v0, vec3 v1, vec3 v2, vec3 h) {
    float p0 = dot(axis, v0), p1 = dot(axis, v1), p2 = dot(axis, v2);
    float r = dot(h, abs(axis));
    return min(p0, min(p1, p2)) > r || max(p0, max(p1, p2)) < -r;
}
bool kd_tri_box_overlap(vec3 a, vec3 b, vec3 c, vec3 lo, vec3 hi) {
    vec3 ctr = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
    vec3 v0 = a - ctr, v1 = b - ctr, v2 = c - ctr;
    if (any(greaterThan(min(min(v0, v1), v2), h)) || any(lessThan(max(max(v0, v1), v2), -h))) return false;
    vec3 e0 = v1 - v0, e1 = v2 - v1, e2 = v0 - v2;
    if (kd_separated(cross(e0, e1), v0, v1, v2, h)) return false;
    const vec3 X = vec3(1.0, 0.0, 0.0), Y = vec3(0.0, 1.0, 0.0), Z = vec3(0.0, 0.0, 1.0);
    if (kd_separated(cross(e0, X), v0, v1, v2, h) || kd_separated(cross(e0, Y), v0, v1, v2, h) || kd_separated(cross(e0, Z), v0, v1, v2, h)) return false;
    if (kd_separated(cross(e1, X), v0, v1, v2, h) || kd_separated(cross(e1, Y), v0, v1, v2, h) || kd_separated(cross(e1, Z), v0, v1, v2, h)) return false;
    if (kd_separated(cross(e2, X), v0, v1, v2, h) || kd_separated(cross(e2, Y), v0, v1, v2, h) || kd_separated(cross(e2, Z), v0, v1, v2, h)) return false;
    return true;
}

// Bounds of triangle ti's box clipped to the cell [blo, bhi] (the build's SAH bins and tight
// bounds).
void ref_bounds(uint ti, vec3 blo, vec3 bhi, out vec3 lo, out vec3 hi) {
    vec3 a = tris[3u * ti].xyz, b = tris[3u * ti + 1u].xyz, c = tris[3u * ti + 2u].xyz;
    lo = max(min(min(a, b), c), blo);
    hi = min(max(max(a, b), c), bhi);
}

// Which children of the cell [blo, bhi] split at `split` on `axis` take triangle ti: those its
// clipped box reaches within eps (one at least) and whose cell, grown by eps, the triangle
// itself overlaps (a triangle whose box reaches a child's cell but which passes beside it goes
// nowhere there: fewer references than the box rule, the same hits).
void kd_children(uint ti, vec3 blo, vec3 bhi, uint axis, float split, float eps, out bool l, out bool r) {
    vec3 a = tris[3u * ti].xyz, b = tris[3u * ti + 1u].xyz, c = tris[3u * ti + 2u].xyz;
    float lo = max(min(min(a[axis], b[axis]), c[axis]), blo[axis]);
    float hi = min(max(max(a[axis], b[axis]), c[axis]), bhi[axis]);
    l = lo <= split + eps;
    r = hi >= split - eps || !l;
    vec3 lhi = bhi, rlo = blo;
    lhi[axis] = split;
    rlo[axis] = split;
    l = l && kd_tri_box_overlap(a, b, c, blo - eps, lhi + eps);
    r = r && kd_tri_box_overlap(a, b, c, rlo - eps, bhi + eps);
}

void kd_list_append(uint level, uint node) {
    uint par = level & 1u;
    uint i = atomicAdd(ctr[KD_LIST_COUNT + par], 1u);
    if (i < KD_LIST_CAP) ctr[KD_LIST_BASE + par * KD_LIST_CAP + i] = node;
    else atomicOr(ctr[KD_LIST_OVERFLOW + par], 1u);
}
#endif
