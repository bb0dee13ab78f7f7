// The diffuse SG lighting of the ISG technique at one point, shared by isg_shade.glsl (per pixel)
// and isg/isg_vertex.comp (per vertex). The including shader declares `vec4 lobes[]` (2 per
// lighting lobe: axis + lambda, rgb mu) and `float visible(vec3 p, vec3 n, SG g)` (the ISG
// visible fraction of g).
#ifndef PENUMBRA_ISG_LOBES_GLSL
#define PENUMBRA_ISG_LOBES_GLSL

// Shadowed diffuse irradiance sum_k e_k V_k of the first nl (<= 64) lobes at p (normal n), and
// the unshadowed sum_k e_k in `unshadowed` (e_k: the unshadowed SG-cosine integral of lobe k;
// V_k: the visible fraction of lobe k times the cosine SG, traversed from the offset point p).
// Lobes are taken in descending order of their e_k here; once the next carries less than
// min_fraction of the light found visible so far, it and every smaller one take the
// energy-weighted mean visibility of the lobes traversed. Measured against the visible light,
// not the unshadowed total, the skip stays small in an umbra: where the dominant lobe (a sun, a
// studio light) is blocked, the sky's lobes are traversed, not given the sun's visibility.
vec3 isg_lobes_diffuse(vec3 p, vec3 n, uint nl, float min_fraction, out vec3 unshadowed) {
    SG cosg = sg_clamped_cosine(n);
    nl = min(nl, 64u);
    float ys[64];
    unshadowed = vec3(0.0);
    for (uint k = 0u; k < nl; ++k) {
        SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        vec3 e = lobes[2u * k + 1u].rgb * max(sg_cosine_integral(l, n), 0.0);
        unshadowed += e;
        ys[k] = dot(e, vec3(0.2126, 0.7152, 0.0722));
    }
    vec3 shadowed = vec3(0.0), skipped = vec3(0.0);
    float vis_sum = 0.0, vis_w = 0.0;
    bool skipping = false;
    for (uint it = 0u; it < nl; ++it) {
        int best = -1;
        float by = 0.0;
        for (uint k = 0u; k < nl; ++k) {
            if (ys[k] > by) {
                by = ys[k];
                best = int(k);
            }
        }
        if (best < 0) break;
        uint k = uint(best);
        ys[k] = -1.0;
        SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        vec3 e = lobes[2u * k + 1u].rgb * max(sg_cosine_integral(l, n), 0.0);
        skipping = skipping || by < min_fraction * vis_sum;
        if (skipping) {
            skipped += e;
            continue;
        }
        float vk = visible(p, n, sg_product(l, cosg));
        shadowed += e * vk;
        vis_sum += vk * by;
        vis_w += by;
    }
    return shadowed + skipped * (vis_w > 0.0 ? vis_sum / vis_w : 1.0);
}

#endif
