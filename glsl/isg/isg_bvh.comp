#version 450
// Sphere LBVH (Karras 2012, "Maximizing parallelism in the construction of BVHs, octrees and k-d
// trees") built in one workgroup: 30-bit Morton codes of the sphere centres, a bitonic sort in
// shared memory, one internal node per thread from the sorted codes, then bounding spheres
// bottom-up (a node is fitted once both children are), every parent bounding its children.
// Layout as passes/src/isg::GpuNode: internal nodes 0..N-2 (root 0), leaves N-1..2N-2;
// a single sphere is a leaf at 0. N <= 1024.

layout(local_size_x = 256) in;

struct IsgNode {
    vec4 sphere;
    ivec4 info;
};

layout(set = 0, binding = 0) readonly buffer Spheres { vec4 spheres[]; };
layout(set = 0, binding = 1) coherent buffer Nodes { IsgNode nodes[]; };
layout(push_constant) uniform Push {
    vec4 lo;        // xyz bounds min of the centres
    vec4 inv_ext;   // xyz 1 / extent
    int count;
} pc;

const int MAXN = 1024;
shared uint s_code[MAXN];
shared uint s_idx[MAXN];
shared uint s_ready[MAXN];
shared uint s_changed;

uint expand_bits(uint v) {
    v = (v * 0x00010001u) & 0xFF0000FFu;
    v = (v * 0x00000101u) & 0x0F00F00Fu;
    v = (v * 0x00000011u) & 0xC30C30C3u;
    v = (v * 0x00000005u) & 0x49249249u;
    return v;
}

int clz32(uint x) {
    return 31 - findMSB(x);
}

int delta(int i, int j, int n) {
    if (j < 0 || j >= n) return -1;
    uint a = s_code[i], b = s_code[j];
    if (a == b) return 32 + clz32(uint(i) ^ uint(j));
    return clz32(a ^ b);
}

vec4 merge(vec4 a, vec4 b) {
    vec3 d = b.xyz - a.xyz;
    float dist = length(d);
    if (dist + b.w <= a.w) return a;
    if (dist + a.w <= b.w) return b;
    float r = 0.5 * (dist + a.w + b.w);
    vec3 c = dist > 0.0 ? a.xyz + d * ((r - a.w) / dist) : a.xyz;
    return vec4(c, r * (1.0 + 1e-5) + 1e-6);
}

void main() {
    int n = min(pc.count, MAXN);
    uint tid = gl_LocalInvocationID.x;
    if (n <= 0) return;
    int p2 = 1;
    while (p2 < n) p2 <<= 1;
    for (int i = int(tid); i < p2; i += 256) {
        if (i < n) {
            vec3 u = clamp((spheres[i].xyz - pc.lo.xyz) * pc.inv_ext.xyz, 0.0, 1.0) * 1023.0;
            s_code[i] = (expand_bits(uint(u.x)) << 2) | (expand_bits(uint(u.y)) << 1) | expand_bits(uint(u.z));
        } else {
            s_code[i] = 0xFFFFFFFFu;
        }
        s_idx[i] = uint(i);
    }
    barrier();
    // Bitonic sort of (code, index), ascending.
    for (int k = 2; k <= p2; k <<= 1) {
        for (int j = k >> 1; j > 0; j >>= 1) {
            for (int i = int(tid); i < p2; i += 256) {
                int l = i ^ j;
                if (l > i) {
                    bool up = (i & k) == 0;
                    uint ci = s_code[i], cl = s_code[l];
                    uint ii = s_idx[i], il = s_idx[l];
                    bool gt = ci > cl || (ci == cl && ii > il);
                    if (gt == up) {
                        s_code[i] = cl; s_code[l] = ci;
                        s_idx[i] = il; s_idx[l] = ii;
                    }
                }
            }
            barrier();
        }
    }
    if (n == 1) {
        if (tid == 0u) nodes[0] = IsgNode(spheres[s_idx[0]], ivec4(-1, -1, int(s_idx[0]), 0));
        return;
    }
    // Leaves.
    for (int i = int(tid); i < n; i += 256) {
        nodes[n - 1 + i] = IsgNode(spheres[s_idx[i]], ivec4(-1, -1, int(s_idx[i]), 0));
        s_ready[i] = 0u;  // internal node i (i < n - 1) not fitted yet
    }
    // Internal nodes (Karras 2012, figure 4).
    for (int i = int(tid); i < n - 1; i += 256) {
        int d = delta(i, i + 1, n) - delta(i, i - 1, n) >= 0 ? 1 : -1;
        int dmin = delta(i, i - d, n);
        int lmax = 2;
        while (delta(i, i + lmax * d, n) > dmin) lmax <<= 1;
        int l = 0;
        for (int t = lmax >> 1; t >= 1; t >>= 1) {
            if (delta(i, i + (l + t) * d, n) > dmin) l += t;
        }
        int j = i + l * d;
        int dnode = delta(i, j, n);
        int s = 0;
        int t = l;
        do {
            t = (t + 1) >> 1;
            if (delta(i, i + (s + t) * d, n) > dnode) s += t;
        } while (t > 1);
        int g = i + s * d + min(d, 0);
        int left = min(i, j) == g ? n - 1 + g : g;
        int right = max(i, j) == g + 1 ? n - 1 + g + 1 : g + 1;
        nodes[i].info = ivec4(left, right, -1, 0);
    }
    memoryBarrierBuffer();
    barrier();
    // Bottom-up bounds: a node is fitted once both children are (leaves are ready).
    for (int it = 0; it < n; ++it) {
        if (tid == 0u) s_changed = 0u;
        barrier();
        for (int i = int(tid); i < n - 1; i += 256) {
            if (s_ready[i] != 0u) continue;
            ivec4 info = nodes[i].info;
            bool lr = info.x >= n - 1 || s_ready[info.x] == 1u;
            bool rr = info.y >= n - 1 || s_ready[info.y] == 1u;
            if (lr && rr) {
                nodes[i].sphere = merge(nodes[info.x].sphere, nodes[info.y].sphere);
                s_changed = 1u;
            }
        }
        memoryBarrierBuffer();
        barrier();
        // Publish readiness after the writes of this round.
        for (int i = int(tid); i < n - 1; i += 256) {
            if (s_ready[i] == 0u) {
                ivec4 info = nodes[i].info;
                bool lr = info.x >= n - 1 || s_ready[info.x] == 1u;
                bool rr = info.y >= n - 1 || s_ready[info.y] == 1u;
                if (lr && rr) s_ready[i] = 2u;
            }
        }
        barrier();
        for (int i = int(tid); i < n - 1; i += 256) {
            if (s_ready[i] == 2u) s_ready[i] = 1u;
        }
        bool done = s_changed == 0u;
        barrier();
        if (done) break;
    }
}
