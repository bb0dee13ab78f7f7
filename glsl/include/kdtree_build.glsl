// Shared by the kd-tree build kernels (kdtree_build.comp, kdtree_small.comp): the large-node
// lists in the header buffer `ctr` (see passes/src/kdtree.rs). Level L's nodes with more than
// small_max references are listed (parity L & 1) by their parents, so the workgroup-per-node
// kernel visits only them; an overflowing list makes that level scan all its nodes.
#ifndef PENUMBRA_KDTREE_BUILD_GLSL
#define PENUMBRA_KDTREE_BUILD_GLSL
#define KD_LIST_COUNT 112u
#define KD_LIST_OVERFLOW 114u
#define KD_LIST_BASE 128u
#define KD_LIST_CAP 4096u

void kd_list_append(uint level, uint node) {
    uint par = level & 1u;
    uint i = atomicAdd(ctr[KD_LIST_COUNT + par], 1u);
    if (i < KD_LIST_CAP) ctr[KD_LIST_BASE + par * KD_LIST_CAP + i] = node;
    else atomicOr(ctr[KD_LIST_OVERFLOW + par], 1u);
}
#endif
