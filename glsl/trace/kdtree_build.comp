#version 460
#extension GL_GOOGLE_include_directive : require
// kd-tree build, one dispatch per tree level (breadth first, after Zhou et al. 2008): every
// workgroup takes pending nodes of this level (persistent loop) and turns each into a leaf or an
// interior node with two pending children of the next level.
//  - large nodes (> large_threshold refs): cut off empty space when one side of the node's cell
//    is more than 25% empty, else split at the spatial median of the longest axis of the refs'
//    tight bounds (the large-node stage of Zhou et al.);
//  - small nodes: binned SAH, 16 bins per axis over the cell (Zhou et al. evaluate every
//    triangle-bound candidate exactly); leaf when no split beats the leaf cost.
// A reference goes to a child when its triangle bounds, clipped to the cell, touch the child's
// cell within eps (conservative: rounding in the traversal cannot skip a triangle).
// Storage of children and their refs is allocated with atomics; on overflow the node becomes a
// leaf (correct, slower) and the overflow flag is set. Nodes with at most small_max references
// are left to kdtree_small.comp (one invocation per node), dispatched after this one.
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Tris { vec4 tris[]; };
layout(std430, binding = 1) buffer Nodes { uvec4 nodes[]; };
layout(std430, binding = 2) buffer Boxes { vec4 boxes[]; };
layout(std430, binding = 3) buffer Refs { uint refs[]; };
layout(std430, binding = 4) buffer Counters { uint ctr[]; };
layout(push_constant) uniform Push {
    uint level;
    uint max_nodes;
    uint ref_cap;
    uint max_depth;
    float eps;
    uint leaf_size;
    uint large_threshold;
    uint small_max;     // nodes with at most this many refs are left to kdtree_small.comp
} pc;

#define NBINS 16
#define C_TRAV 1.0
#define C_ISECT 1.5

shared uint s_lo[3];
shared uint s_hi[3];
shared uint s_bmin[3 * NBINS];
shared uint s_bmax[3 * NBINS];
shared uint s_count[2];
shared uint s_wpos[2];
shared uint s_axis;
shared float s_split;
shared uint s_mode;        // 0 leaf, 1 split
shared uint s_child;
shared uint s_off[2];

#include "kdtree_build.glsl"

uint f2o(float f) { uint u = floatBitsToUint(f); return (u & 0x80000000u) != 0u ? ~u : (u | 0x80000000u); }
float o2f(uint u) { return uintBitsToFloat((u & 0x80000000u) != 0u ? (u & 0x7fffffffu) : ~u); }


void main() {
    uint tid = gl_LocalInvocationIndex;
    uint L = pc.level;
    uint base = ctr[64u + L];
    uint avail = pc.max_nodes > base ? (pc.max_nodes - base) & ~1u : 0u;
    uint cnt = min(ctr[16u + L], avail);
    uint next_base = base + cnt;
    uint next_avail = pc.max_nodes > next_base ? (pc.max_nodes - next_base) & ~1u : 0u;
    if (gl_WorkGroupID.x == 0u && tid == 0u && L + 1u < 48u) ctr[64u + L + 1u] = next_base;

    // Large nodes of this level: from the list their parents appended (parity L & 1), or every
    // node of the level when that list overflowed.
    uint par = L & 1u;
    bool scan_all = ctr[KD_LIST_OVERFLOW + par] != 0u;
    uint todo = scan_all ? cnt : min(ctr[KD_LIST_COUNT + par], KD_LIST_CAP);
    for (uint k = gl_WorkGroupID.x; k < todo; k += gl_NumWorkGroups.x) {
        uint ni = scan_all ? base + k : ctr[KD_LIST_BASE + par * KD_LIST_CAP + k];
        uvec4 nd = nodes[ni];
        uint off = nd.z, n = nd.w;
        if (nd.y == 4u && n <= pc.small_max) continue;   // small node: kdtree_small.comp (uniform per workgroup)
        vec3 blo = boxes[2u * ni].xyz, bhi = boxes[2u * ni + 1u].xyz;
        bool make_leaf = nd.y != 4u || n <= pc.leaf_size || L + 1u >= pc.max_depth;
        if (tid == 0u) { s_mode = 0u; s_count[0] = 0u; s_count[1] = 0u; s_wpos[0] = 0u; s_wpos[1] = 0u; }
        if (!make_leaf) {
            if (n > pc.large_threshold) {
                // ---- large node: tight bounds, empty-space cut or spatial median
                if (tid < 3u) { s_lo[tid] = 0xffffffffu; s_hi[tid] = 0u; }
                barrier();
                for (uint j = tid; j < n; j += 64u) {
                    vec3 lo, hi;
                    ref_bounds(refs[off + j], blo, bhi, lo, hi);
                    for (int a = 0; a < 3; a++) { atomicMin(s_lo[a], f2o(lo[a])); atomicMax(s_hi[a], f2o(hi[a])); }
                }
                barrier();
                if (tid == 0u) {
                    vec3 tlo = max(vec3(o2f(s_lo[0]), o2f(s_lo[1]), o2f(s_lo[2])), blo);
                    vec3 thi = min(vec3(o2f(s_hi[0]), o2f(s_hi[1]), o2f(s_hi[2])), bhi);
                    vec3 ext = bhi - blo;
                    float best_gap = 0.25;
                    int axis = -1;
                    float split = 0.0;
                    for (int a = 0; a < 3; a++) {
                        if (ext[a] <= 4.0 * pc.eps) continue;
                        float gl = (tlo[a] - blo[a]) / ext[a], gh = (bhi[a] - thi[a]) / ext[a];
                        if (gl > best_gap && tlo[a] - blo[a] > 4.0 * pc.eps) { best_gap = gl; axis = a; split = tlo[a] - 2.0 * pc.eps; }
                        if (gh > best_gap && bhi[a] - thi[a] > 4.0 * pc.eps) { best_gap = gh; axis = a; split = thi[a] + 2.0 * pc.eps; }
                    }
                    if (axis < 0) {
                        vec3 te = thi - tlo;
                        axis = te.x >= te.y ? (te.x >= te.z ? 0 : 2) : (te.y >= te.z ? 1 : 2);
                        split = 0.5 * (tlo[axis] + thi[axis]);
                        if (!(te[axis] > 4.0 * pc.eps)) axis = -1;
                    }
                    if (axis >= 0) { s_mode = 1u; s_axis = uint(axis); s_split = split; }
                }
            } else {
                // ---- small node: binned SAH over the cell
                for (uint j = tid; j < 3u * NBINS; j += 64u) { s_bmin[j] = 0u; s_bmax[j] = 0u; }
                barrier();
                vec3 ext = bhi - blo;
                vec3 scale = vec3(NBINS) / max(ext, vec3(1e-30));
                for (uint j = tid; j < n; j += 64u) {
                    vec3 lo, hi;
                    ref_bounds(refs[off + j], blo, bhi, lo, hi);
                    for (int a = 0; a < 3; a++) {
                        int b0 = clamp(int((lo[a] - blo[a]) * scale[a]), 0, NBINS - 1);
                        int b1 = clamp(int((hi[a] - blo[a]) * scale[a]), 0, NBINS - 1);
                        atomicAdd(s_bmin[a * NBINS + b0], 1u);
                        atomicAdd(s_bmax[a * NBINS + b1], 1u);
                    }
                }
                barrier();
                if (tid == 0u) {
                    float area = 2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x);
                    float best = C_ISECT * float(n);
                    int best_axis = -1;
                    float best_split = 0.0;
                    for (int a = 0; a < 3; a++) {
                        if (ext[a] <= 4.0 * pc.eps) continue;
                        int a1 = (a + 1) % 3, a2 = (a + 2) % 3;
                        float cap = 2.0 * ext[a1] * ext[a2], rim = 2.0 * (ext[a1] + ext[a2]);
                        uint total_max = 0u;
                        for (int b = 0; b < NBINS; b++) total_max += s_bmax[a * NBINS + b];
                        uint nl = 0u, nr = total_max;
                        for (int b = 1; b < NBINS; b++) {
                            nl += s_bmin[a * NBINS + b - 1];
                            nr -= s_bmax[a * NBINS + b - 1];
                            float wl = ext[a] * float(b) / float(NBINS);
                            float al = cap + rim * wl, ar = cap + rim * (ext[a] - wl);
                            float c = C_TRAV + C_ISECT * (al * float(nl) + ar * float(nr)) / max(area, 1e-30);
                            if (c < best) { best = c; best_axis = a; best_split = blo[a] + wl; }
                        }
                    }
                    if (best_axis >= 0) { s_mode = 1u; s_axis = uint(best_axis); s_split = best_split; }
                }
            }
        }
        barrier();
        uint mode = s_mode;
        uint axis = s_axis;
        float split = s_split;
        if (mode == 1u) {
            // ---- count
            uint cl = 0u, cr = 0u;
            for (uint j = tid; j < n; j += 64u) {
                bool l, r;
                kd_children(refs[off + j], blo, bhi, axis, split, pc.eps, l, r);
                cl += l ? 1u : 0u;
                cr += r ? 1u : 0u;
            }
            atomicAdd(s_count[0], cl);
            atomicAdd(s_count[1], cr);
            barrier();
            if (tid == 0u) {
                uint nl = s_count[0], nr = s_count[1];
                bool ok = !(nl == n && nr == n);
                if (ok) {
                    uint o = atomicAdd(ctr[0], nl + nr);
                    if (o > pc.ref_cap || nl + nr > pc.ref_cap - o) { ok = false; atomicOr(ctr[4], 1u); }
                    else { s_off[0] = o; s_off[1] = o + nl; }
                }
                if (ok) {
                    uint v = atomicAdd(ctr[16u + L + 1u], 2u);
                    if (v + 2u > next_avail) { ok = false; atomicOr(ctr[4], 2u); }
                    else s_child = next_base + v;
                }
                if (!ok) s_mode = 0u;
            }
            barrier();
            mode = s_mode;
            if (mode == 1u) {
                // ---- distribute
                uint ol = s_off[0], orr = s_off[1];
                for (uint j = tid; j < n; j += 64u) {
                    uint ti = refs[off + j];
                    bool l, r;
                    kd_children(ti, blo, bhi, axis, split, pc.eps, l, r);
                    if (l) refs[ol + atomicAdd(s_wpos[0], 1u)] = ti;
                    if (r) refs[orr + atomicAdd(s_wpos[1], 1u)] = ti;
                }
                if (tid == 0u) {
                    uint c = s_child;
                    nodes[ni] = uvec4(floatBitsToUint(split), axis, c, 0u);
                    nodes[c] = uvec4(0u, 4u, ol, s_count[0]);
                    nodes[c + 1u] = uvec4(0u, 4u, orr, s_count[1]);
                    if (s_count[0] > pc.small_max) kd_list_append(L + 1u, c);
                    if (s_count[1] > pc.small_max) kd_list_append(L + 1u, c + 1u);
                    vec3 lhi = bhi, rlo = blo;
                    lhi[axis] = split;
                    rlo[axis] = split;
                    boxes[2u * c] = vec4(blo, 0.0);
                    boxes[2u * c + 1u] = vec4(lhi, 0.0);
                    boxes[2u * c + 2u] = vec4(rlo, 0.0);
                    boxes[2u * c + 3u] = vec4(bhi, 0.0);
                }
            }
        }
        if (mode == 0u && tid == 0u) {
            nodes[ni] = uvec4(0u, 3u, off, n);
            atomicAdd(ctr[1], 1u);
            atomicAdd(ctr[2], n);
            atomicMax(ctr[3], L);
            if (n == 0u) atomicAdd(ctr[5], 1u);
        }
        barrier();
    }
}
