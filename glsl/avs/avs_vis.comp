#version 460
#extension GL_GOOGLE_include_directive : require
// Adaptive angular visibility sampling (Wang et al., section 4.2), one level per dispatch: one
// workgroup per sample point of the batch. Level 0 traces every texel of the initial grid
// (res x res, e.g. 16 x 16); level L (res = 2 x the previous) traces a texel only when its parent
// texel of the previous level is a boundary texel (its 8-neighbourhood holds both states) in this
// point's previous map, or in a neighbouring sample point's previous map at the same direction;
// other texels take the parent's value. Every level writes a full r x r packed map (texel blocks
// replicated) in the layout of include/avs_maps.glsl; rays are any-hit queries through the
// kd-tree (include/kdtree.glsl) from the point offset along its normal. The map is assembled with
// atomicOr directly in the output buffer (each workgroup first zeroes the words of its rows). A
// workgroup first lists the texels it traces in shared memory, then traces the list, 64 rays
// abreast.
//
// Work split: one workgroup per (batch entry, chunk of AVS_VIS_CHUNK texels of this level), so an
// invocation traces at most AVS_VIS_CHUNK / 64 = 16 rays. lavapipe (gallivm) ends EVERY loop of a
// shader invocation once its loops have run 65535 iterations in total (LP_MAX_TGSI_LOOP_ITERATIONS,
// one counter shared by all loops of the shader, per SIMD group of invocations), silently: with one
// workgroup per map, an invocation traced 1024 rays at r = 256 (each ray a kd-tree loop of tens to
// hundreds of iterations), its texel loop stopped early and the untraced texels stayed 0 =
// occluded (the r = 256 "spurious occlusion" of issue 8: the last 8 invocations of the workgroup,
// columns 56-63 mod 64 of the last ~50 rows). The probe loop at the end (pc.probe = 2 iterations)
// detects an exhausted counter and sets bit 31 of the entry's ray count (the CPU reports it).
#include "avs_maps.glsl"

layout(local_size_x = 64) in;
layout(binding = 0) uniform usamplerBuffer kd_tris;
layout(binding = 1) uniform usamplerBuffer kd_nodes;
layout(binding = 2) uniform usamplerBuffer kd_refs;
layout(std430, binding = 3) readonly buffer Header { uint kd_hdr[]; };
// The points, the batch and the previous level's maps are read through texel buffers (one
// gather per 16-byte texel on a CPU device, where a storage-buffer read is a scalar load per lane
// and component):
// 3 texels per slot: (position, normal offset), (tangent, 0), (normal, 0) as float bits
layout(binding = 4) uniform usamplerBuffer pts_t;
// [0, count): slot of batch entry e; then count * K neighbour batch entries (0xffffffff: none),
// four to a texel
layout(binding = 5) uniform usamplerBuffer batch_t;
// previous level's maps, indexed by batch entry, four words to a texel (unused at level 0)
layout(binding = 6) uniform usamplerBuffer prev_t;
#define PTS(i) uintBitsToFloat(texelFetch(pts_t, int(i)))
#define BATCH(i) (texelFetch(batch_t, int((i) >> 2u))[(i) & 3u])
#define PREV_WORD(i) (texelFetch(prev_t, int((i) >> 2u))[(i) & 3u])
// this level's maps: indexed by batch entry (scratch) or by slot (final level); read-write
// (atomicOr)
layout(std430, binding = 7) coherent buffer Out { uint outw[]; };
// rays traced per batch entry (statistics), accumulated over the levels; bit 31: a workgroup of
// this entry hit the driver's loop limit (see above)
layout(std430, binding = 8) buffer Stats { uint stats[]; };
layout(push_constant) uniform Push {
    uint r;        // final resolution
    uint res;      // this level's resolution
    uint count;    // batch entries
    uint k;        // neighbours per entry
    uint level;    // 0: initial grid
    uint to_slot;  // 1: write map of entry e at its slot (final level)
    uint flags;    // bit 0: neighbours' maps mark boundary rays; bit 1: trace every texel (no adaptivity);
                   // bit 2: keep hits whose children all miss (see main)
    uint probe;    // 2: trip count of the loop-limit probe
} pc;

// texels of one workgroup (a multiple of every level's res <= 256)
#define AVS_VIS_CHUNK 1024u

#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"

shared uint straced;
// this workgroup's texels to trace at this level (pass 1 lists them, pass 2 traces them, so that
// a level's scattered boundary texels fill whole SIMD groups; no gain measured on lavapipe, where
// the boundary rays' own length dominates, and none measured on a GPU yet)
shared uint slist[AVS_VIS_CHUNK];
shared uint scount;
// level > 0: per texel of the previous level under this workgroup's rows, bit 0: its children are
// traced (a boundary texel here or in a neighbour's map), bit 1: its value (the test is per
// parent, so it is made once for its four children)
shared uint sparent[AVS_VIS_CHUNK / 4u];

// Value of texel (a, b) of the previous level (resolution pres) of batch entry e.
bool prev_bit(uint e, uint a, uint b, uint pres) {
    uint s = pc.r / pres;
    uint kk = (a * s) * pc.r + b * s;
    return ((PREV_WORD(e * avs_words_per_map(pc.r) + (kk >> 5u)) >> (kk & 31u)) & 1u) == 1u;
}

// Texel (a, b) of the previous level has a neighbour (8-neighbourhood, no wrap in phi) of the
// other state.
bool boundary(uint e, uint a, uint b, uint pres) {
    bool v = prev_bit(e, a, b, pres);
    for (int da = -1; da <= 1; ++da) {
        for (int db = -1; db <= 1; ++db) {
            int na = int(a) + da, nb = int(b) + db;
            if ((da == 0 && db == 0) || na < 0 || nb < 0 || na >= int(pres) || nb >= int(pres)) continue;
            if (prev_bit(e, uint(na), uint(nb), pres) != v) return true;
        }
    }
    return false;
}

// Sets texel (a, b)'s s x s block of the full-resolution map at word `base` (s divides 32: one
// word per row).
void set_block(uint base, uint a, uint b, uint s) {
    uint mask = s >= 32u ? 0xffffffffu : ((1u << s) - 1u);
    for (uint row = a * s; row < a * s + s; ++row) {
        uint kk = row * pc.r + b * s;
        atomicOr(outw[base + (kk >> 5u)], mask << (kk & 31u));
    }
}

mat3 frame_of(uint slot) {
    vec3 t = PTS(3u * slot + 1u).xyz, n = PTS(3u * slot + 2u).xyz;
    return mat3(t, cross(n, t), n);
}

void main() {
    uint words = avs_words_per_map(pc.r);
    uint tid = gl_LocalInvocationID.x;
    uint res = pc.res, pres = res / 2u, s = pc.r / res;
    uint chunk_len = min(AVS_VIS_CHUNK, res * res);
    // texels [t0, t1) of this level = rows [t0 / res, t1 / res) = full-resolution words [w0, w1)
    uint t0 = gl_WorkGroupID.y * chunk_len, t1 = t0 + chunk_len;
    uint w0 = (t0 / res) * s * pc.r / 32u, w1 = (t1 / res) * s * pc.r / 32u;
    for (uint e = gl_WorkGroupID.x; e < pc.count; e += gl_NumWorkGroups.x) {
        uint slot = BATCH(e);
        uint base = (pc.to_slot != 0u ? slot : e) * words;
        for (uint w = w0 + tid; w < w1; w += 64u) outw[base + w] = 0u;
        if (tid == 0u) {
            straced = 0u;
            scount = 0u;
        }
        memoryBarrierBuffer();
        barrier();
        vec4 p0 = PTS(3u * slot);
        mat3 fr = frame_of(slot);
        vec3 origin = p0.xyz + fr[2] * p0.w;
        uint traced = 0u;
        bool refine = pc.level > 0u && (pc.flags & 2u) == 0u;
        uint pr0 = t0 / res / 2u;
        if (refine) {
            for (uint g = tid; g < chunk_len / 4u; g += 64u) {
                uint pa = pr0 + g / pres, pb = g % pres;
                bool trace_it = boundary(e, pa, pb, pres);
                if (!trace_it && (pc.flags & 1u) != 0u) {
                    vec3 wd = fr * avs_texel_dir(pa, pb, pres);
                    for (uint q = 0u; q < pc.k && !trace_it; ++q) {
                        uint ne = BATCH(pc.count + e * pc.k + q);
                        if (ne == 0xffffffffu) break;
                        mat3 fq = frame_of(BATCH(ne));
                        uvec2 ij;
                        if (avs_dir_to_texel(transpose(fq) * wd, pres, ij)) trace_it = boundary(ne, ij.x, ij.y, pres);
                    }
                }
                sparent[g] = (trace_it ? 1u : 0u) | (prev_bit(e, pa, pb, pres) ? 2u : 0u);
            }
            memoryBarrierShared();
            barrier();
        }
        for (uint t = t0 + tid; t < t1; t += 64u) {
            uint a = t / res, b = t % res;
            bool trace_it = !refine;
            bool value = false;
            if (refine) {
                uint f = sparent[(a / 2u - pr0) * pres + b / 2u];
                trace_it = (f & 1u) != 0u;
                value = (f & 2u) != 0u;
            }
            if (trace_it) {
                slist[atomicAdd(scount, 1u)] = t;
            } else if (value) {
                set_block(base, a, b, s);
            }
        }
        memoryBarrierShared();
        barrier();
        uint listed = scount;
        for (uint i = tid; i < listed; i += 64u) {
            uint t = slist[i];
            uint a = t / res, b = t % res;
            traced++;
            if (kd_trace(origin, fr * avs_texel_dir(a, b, res), 0.0, 1e30, true).t < 0.0) set_block(base, a, b, s);
        }
        // Keeping hits (bit 2; issue 8, slim occluders): the boundary refinement re-traces an
        // occluded parent's four children, and an occluder thinner than a child cell that the
        // parent's ray hit can pass between the children's centre rays: all four miss and the hit is
        // lost (with it the boundary that would refine the occluder further). Such a group keeps
        // one child occluded when a ray confirms the occluder: the parent's centre ray (its
        // direction is the top-left corner of child (2pa+1, 2pb+1)) or, for a parent that was
        // itself kept this way, its top-left corner ray (the corner of child (2pa, 2pb)). A kept
        // texel thus always has a hit on its top-left corner, and the next level refines around
        // it. (Not in the paper, which only refines boundary rays.)
        if (pc.level > 0u && (pc.flags & 6u) == 4u) {
            memoryBarrierBuffer();
            barrier();
            float hp = float(AVS_PI) / float(pres);
            uint mask = s >= 32u ? 0xffffffffu : ((1u << s) - 1u);
            for (uint g = (t0 / res / 2u) * pres + tid; g < (t1 / res / 2u) * pres; g += 64u) {
                uint pa = g / pres, pb = g % pres;
                if (prev_bit(e, pa, pb, pres)) continue;
                bool all_missed = true;
                for (uint c = 0u; c < 4u; ++c) {
                    uint kk = ((2u * pa + c / 2u) * s) * pc.r + (2u * pb + c % 2u) * s;
                    all_missed = all_missed && AVS_VIS_BIT(outw, base, kk);
                }
                if (!all_missed) continue;
                uint ka = 0xffffffffu, kb = 0u;
                traced++;
                if (kd_trace(origin, fr * avs_texel_dir(pa, pb, pres), 0.0, 1e30, true).t >= 0.0) {
                    ka = 2u * pa + 1u;
                    kb = 2u * pb + 1u;
                } else if (pa > 0u && pb > 0u) {
                    traced++;
                    vec3 corner = fr * avs_angles_to_local(float(pa) * hp, float(pb) * hp);
                    if (kd_trace(origin, corner, 0.0, 1e30, true).t >= 0.0) {
                        ka = 2u * pa;
                        kb = 2u * pb;
                    }
                }
                if (ka == 0xffffffffu) continue;
                for (uint row = ka * s; row < ka * s + s; ++row) {
                    uint kk = row * pc.r + kb * s;
                    atomicAnd(outw[base + (kk >> 5u)], ~(mask << (kk & 31u)));
                }
            }
        }
        // loop-limit probe: pc.probe iterations unless the driver's loop counter ran out
        uint probe = 0u;
        for (uint i = 0u; i < pc.probe; ++i) probe++;
        atomicAdd(straced, traced);
        barrier();
        uint cut = probe != pc.probe ? 0x80000000u : 0u;
        if (cut != 0u) atomicOr(straced, cut);
        barrier();
        // (the counts are cleared before the first level)
        if (tid == 0u) {
            atomicOr(stats[e], straced & 0x80000000u);
            atomicAdd(stats[e], straced & 0x7fffffffu);
        }
        barrier();
    }
}
