// Neighbouring sample points of a shading point (Wang et al., section 6): the points within the
// search radius (uniform grid built on the CPU) with the smallest e_g (eq. 6), weighted by inverse
// e_g (eq. 8). Shared by avs_shade.comp (which interpolates their SSDFs) and avs_cull.comp (which
// flags the points some pixel needs, the section 6 "Optimization").
// Before including, declare the buffers
//   pts[]  : 3 vec4 per slot: (position, offset), (tangent, active), (normal, 1: buried)
//   grid[] : [0..2] dims, [4..6] lower corner (float bits), [7] cell edge (float bits), [8] first
//            item word; cell_start at 16 (cells + 1 entries, relative to the first item word),
//            then slots
// or define AVS_PTS(i) (vec4) and AVS_GRID(i) (uint) reading them from elsewhere (avs_shade.comp:
// texel buffers).
#ifndef PENUMBRA_AVS_GATHER_GLSL
#define PENUMBRA_AVS_GATHER_GLSL
#ifndef AVS_PTS
#define AVS_PTS(i) pts[i]
#endif
#ifndef AVS_GRID
#define AVS_GRID(i) grid[i]
#endif

#define MAXN 8
uint nb_slot[MAXN];
float nb_w[MAXN];
mat3 nb_frame[MAXN];
uint nb_count = 0u;

// Fills nb_slot / nb_w / nb_frame / nb_count for the shading point (pos, n): at most m points
// within `radius` whose normal faces the same side, ranked by e_g = alpha |dp| inv_scale +
// sqrt(2 - 2 n.n'). Neighbours off the pixel's tangent plane by more than a quarter of the radius
// lie on other surfaces (cloth under a hat brim): skipped unless nothing else is found (then the
// radius grows 2.5x, then 5x and 10x, then the plane test is dropped at 2.5x). The wider passes
// find the points of surfaces sampled more sparsely than the mean spacing the radius follows (a
// big floor beside a finely meshed dish at the paper's vertex counts: without them discs around
// its points were shadowed and the floor between them drawn unshadowed); they scan the grid's
// coarse level (passes::avs::grid_words). Buried points (every direction occluded: a
// candidate inside a closed object, or under something that closes its hemisphere) are taken only
// when they are clearly the nearest (no unburied candidate within sqrt(2) of the nearest buried
// one's distance: the pixel lies where the object stands, or in the closed space); otherwise only
// the others: a buried map stands for no visible surface beside the object (interpolated there it
// drew black rings around the objects on a floor).
// Insertion of candidate (e, slot) into the ascending list es/slots of count entries (at most m),
// in avs_gather's scope (a macro: GLSL passes arrays by copy).
#define AVS_KEEP_BEST(count, es, slots)                          \
    if (!(count == m && e >= es[m - 1u])) {                      \
        uint j = count < m ? count++ : m - 1u;                   \
        while (j > 0u && es[j - 1u] > e) {                       \
            es[j] = es[j - 1u];                                  \
            slots[j] = slots[j - 1u];                            \
            --j;                                                 \
        }                                                        \
        es[j] = e;                                               \
        slots[j] = slot;                                         \
    }

void avs_gather(vec3 pos, vec3 n, float radius, float alpha, float inv_scale, uint max_neighbours) {
    // the m smallest e_g of all candidates (nb_*, best_e) and of the unburied ones (open_*)
    float best_e[MAXN];
    float open_e[MAXN];
    uint open_slot[MAXN];
    uint open_count = 0u;
    uint m = min(max_neighbours, uint(MAXN));
    nb_count = 0u;
    float near_buried = 1e30, near_open = 1e30;
    for (int pass = 0; pass < 5 && nb_count == 0u; ++pass) {
        float rad = radius * (pass == 0 ? 1.0 : (pass == 2 ? 5.0 : (pass == 3 ? 10.0 : 2.5)));
        float plane_tol = pass == 4 ? 1e30 : 0.25 * rad;
        // the fine level (cells of the radius), the coarse one (word 3: cells of 4 x the radius)
        // for the passes at 5 and 10 x the radius
        uint g0 = pass == 2 || pass == 3 ? AVS_GRID(3) : 0u;
        uvec3 dims = uvec3(AVS_GRID(g0), AVS_GRID(g0 + 1u), AVS_GRID(g0 + 2u));
        vec3 lo = vec3(uintBitsToFloat(AVS_GRID(g0 + 4u)), uintBitsToFloat(AVS_GRID(g0 + 5u)), uintBitsToFloat(AVS_GRID(g0 + 6u)));
        float cell = uintBitsToFloat(AVS_GRID(g0 + 7u));
        uint items = AVS_GRID(g0 + 8u);
        ivec3 a = clamp(ivec3(floor((pos - rad - lo) / cell)), ivec3(0), ivec3(dims) - 1);
        ivec3 b = clamp(ivec3(floor((pos + rad - lo) / cell)), ivec3(0), ivec3(dims) - 1);
        for (int z = a.z; z <= b.z; ++z)
            for (int y = a.y; y <= b.y; ++y)
                for (int x = a.x; x <= b.x; ++x) {
                    uint ci = uint(x) + dims.x * (uint(y) + dims.y * uint(z));
                    uint s0 = AVS_GRID(g0 + 16u + ci), s1 = AVS_GRID(g0 + 17u + ci);
                    for (uint it = s0; it < s1; ++it) {
                        uint slot = AVS_GRID(items + it);
                        vec3 p = AVS_PTS(3u * slot).xyz;
                        vec4 pnb = AVS_PTS(3u * slot + 2u);
                        vec3 pn = pnb.xyz;
                        vec3 dp = p - pos;
                        if (dot(dp, dp) > rad * rad || dot(pn, n) <= 0.0 || abs(dot(dp, n)) > plane_tol) continue;
                        float e = alpha * length(dp) * inv_scale + sqrt(max(2.0 - 2.0 * dot(n, pn), 0.0));
                        bool buried = pnb.w > 0.5;
                        if (buried) near_buried = min(near_buried, dot(dp, dp));
                        else near_open = min(near_open, dot(dp, dp));
                        // keep the m smallest e_g, of all and of the unburied
                        AVS_KEEP_BEST(nb_count, best_e, nb_slot);
                        if (!buried) AVS_KEEP_BEST(open_count, open_e, open_slot);
                    }
                }
    }
    if (open_count > 0u && near_open <= 2.0 * near_buried) {
        nb_count = open_count;
        for (uint q = 0u; q < open_count; ++q) {
            best_e[q] = open_e[q];
            nb_slot[q] = open_slot[q];
        }
    }
    float sum = 0.0;
    for (uint q = 0u; q < nb_count; ++q) {
        nb_w[q] = 1.0 / max(best_e[q], 1e-6);
        sum += nb_w[q];
        vec3 t = AVS_PTS(3u * nb_slot[q] + 1u).xyz, pn = AVS_PTS(3u * nb_slot[q] + 2u).xyz;
        nb_frame[q] = mat3(t, cross(pn, t), pn);
    }
    for (uint q = 0u; q < nb_count; ++q) nb_w[q] /= sum;
}

#endif
