#version 460
#extension GL_GOOGLE_include_directive : require
// kd-tree build, small-node stage of one level (after kdtree_build.comp's large nodes of the
// same level): one invocation per pending node with at most small_max references (Zhou et al.
// also give each small node one thread), binned SAH (16 bins per axis over the cell), the same
// conservative reference assignment, allocation and overflow rules as kdtree_build.comp.
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
    uint small_max;
} pc;

#define NBINS 16
#define C_TRAV 1.0
#define C_ISECT 1.5

#include "kdtree_build.glsl"


void main() {
    uint L = pc.level;
    uint base = ctr[64u + L];
    uint avail = pc.max_nodes > base ? (pc.max_nodes - base) & ~1u : 0u;
    uint cnt = min(ctr[16u + L], avail);
    uint next_base = base + cnt;
    uint next_avail = pc.max_nodes > next_base ? (pc.max_nodes - next_base) & ~1u : 0u;
    uint stride = gl_NumWorkGroups.x * 64u;
    // The large-node list this level's kdtree_build.comp consumed is free again: it becomes the
    // list of level L + 2 (nobody appends to it during this dispatch).
    if (gl_GlobalInvocationID.x == 0u) { ctr[KD_LIST_COUNT + (L & 1u)] = 0u; ctr[KD_LIST_OVERFLOW + (L & 1u)] = 0u; }
    for (uint k = gl_GlobalInvocationID.x; k < cnt; k += stride) {
        uint ni = base + k;
        uvec4 nd = nodes[ni];
        uint off = nd.z, n = nd.w;
        if (nd.y != 4u || n > pc.small_max) continue;   // done, or a large node
        vec3 blo = boxes[2u * ni].xyz, bhi = boxes[2u * ni + 1u].xyz;
        bool split_ok = !(n <= pc.leaf_size || L + 1u >= pc.max_depth);
        uint axis = 0u;
        float split = 0.0;
        if (split_ok) {
            uint bmin[3 * NBINS], bmax[3 * NBINS];
            for (int j = 0; j < 3 * NBINS; j++) { bmin[j] = 0u; bmax[j] = 0u; }
            vec3 ext = bhi - blo;
            vec3 scale = vec3(NBINS) / max(ext, vec3(1e-30));
            for (uint j = 0u; j < n; j++) {
                vec3 lo, hi;
                ref_bounds(refs[off + j], blo, bhi, lo, hi);
                for (int a = 0; a < 3; a++) {
                    bmin[a * NBINS + clamp(int((lo[a] - blo[a]) * scale[a]), 0, NBINS - 1)]++;
                    bmax[a * NBINS + clamp(int((hi[a] - blo[a]) * scale[a]), 0, NBINS - 1)]++;
                }
            }
            float area = 2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x);
            float best = C_ISECT * float(n);
            int best_axis = -1;
            for (int a = 0; a < 3; a++) {
                if (ext[a] <= 4.0 * pc.eps) continue;
                int a1 = (a + 1) % 3, a2 = (a + 2) % 3;
                float cap = 2.0 * ext[a1] * ext[a2], rim = 2.0 * (ext[a1] + ext[a2]);
                uint nl = 0u, nr = n;
                for (int b = 1; b < NBINS; b++) {
                    nl += bmin[a * NBINS + b - 1];
                    nr -= bmax[a * NBINS + b - 1];
                    float wl = ext[a] * float(b) / float(NBINS);
                    float al = cap + rim * wl, ar = cap + rim * (ext[a] - wl);
                    float c = C_TRAV + C_ISECT * (al * float(nl) + ar * float(nr)) / max(area, 1e-30);
                    if (c < best) { best = c; best_axis = a; split = blo[a] + wl; }
                }
            }
            split_ok = best_axis >= 0;
            axis = uint(max(best_axis, 0));
        }
        uint nl = 0u, nr = 0u;
        if (split_ok) {
            for (uint j = 0u; j < n; j++) {
                bool l, r;
                kd_children(refs[off + j], blo, bhi, axis, split, pc.eps, l, r);
                nl += l ? 1u : 0u;
                nr += r ? 1u : 0u;
            }
            split_ok = !(nl == n && nr == n);
        }
        uint ol = 0u, child = 0u;
        if (split_ok) {
            uint o = atomicAdd(ctr[0], nl + nr);
            if (o > pc.ref_cap || nl + nr > pc.ref_cap - o) { split_ok = false; atomicOr(ctr[4], 1u); }
            else ol = o;
        }
        if (split_ok) {
            uint v = atomicAdd(ctr[16u + L + 1u], 2u);
            if (v + 2u > next_avail) { split_ok = false; atomicOr(ctr[4], 2u); }
            else child = next_base + v;
        }
        if (split_ok) {
            uint orr = ol + nl, wl = 0u, wr = 0u;
            for (uint j = 0u; j < n; j++) {
                uint ti = refs[off + j];
                bool l, r;
                kd_children(ti, blo, bhi, axis, split, pc.eps, l, r);
                if (l) refs[ol + wl++] = ti;
                if (r) refs[orr + wr++] = ti;
            }
            nodes[ni] = uvec4(floatBitsToUint(split), axis, child, 0u);
            nodes[child] = uvec4(0u, 4u, ol, nl);
            nodes[child + 1u] = uvec4(0u, 4u, orr, nr);
            if (nl > pc.small_max) kd_list_append(L + 1u, child);
            if (nr > pc.small_max) kd_list_append(L + 1u, child + 1u);
            vec3 lhi = bhi, rlo = blo;
            lhi[axis] = split;
            rlo[axis] = split;
            boxes[2u * child] = vec4(blo, 0.0);
            boxes[2u * child + 1u] = vec4(lhi, 0.0);
            boxes[2u * child + 2u] = vec4(rlo, 0.0);
            boxes[2u * child + 3u] = vec4(bhi, 0.0);
        } else {
            nodes[ni] = uvec4(0u, 3u, off, n);
            atomicAdd(ctr[1], 1u);
            atomicAdd(ctr[2], n);
            atomicMax(ctr[3], L);
            if (n == 0u) atomicAdd(ctr[5], 1u);
        }
    }
}
