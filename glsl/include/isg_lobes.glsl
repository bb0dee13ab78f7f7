// The diffuse SG lighting of the ISG technique at one point, shared by isg_shade.glsl (per pixel)
// and isg/isg_vertex.comp (per vertex). The including shader declares `vec4 lobes[]` (2 per
// lighting lobe: axis + lambda, rgb mu) and `float visible(vec3 p, vec3 n, SG g)` (the ISG
// visible fraction of g).
#ifndef PENUMBRA_ISG_LOBES_GLSL
#define PENUMBRA_ISG_LOBES_GLSL

// Shadowed light sum_k e_k V_k of the first nl (<= 64) lobes at p (normal n) through `kernel`,
// and the unshadowed sum_k e_k in `unshadowed`. With `cosine` (diffuse; kernel: the clamped
// cosine SG of n) e_k is lobe k's unshadowed SG-cosine integral; without (glossy; kernel: the
// BRDF's specular SG lobe times the cosine) e_k is the lobe's inner product with the kernel. V_k:
// the visible fraction of lobe k times the kernel, traversed from the offset point p.
// Lobes are taken in descending order of their e_k here; once the next carries less than
// min_fraction of the light found visible so far, it and every smaller one take the
// energy-weighted mean visibility of the lobes traversed. Measured against the visible light,
// not the unshadowed total, the skip stays small in an umbra: where the dominant lobe (a sun, a
// studio light) is blocked, the sky's lobes are traversed, not given the sun's visibility.
vec3 isg_lobes_shadowed(vec3 p, vec3 n, uint nl, float min_fraction, SG kernel, bool cosine, out vec3 unshadowed) {
    nl = min(nl, 64u);
    float ys[64];
    unshadowed = vec3(0.0);
    for (uint k = 0u; k < nl; ++k) {
        SG l = sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        vec3 e = lobes[2u * k + 1u].rgb * max(cosine ? sg_cosine_integral(l, n) : sg_inner_product(l, kernel), 0.0);
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
        vec3 e = lobes[2u * k + 1u].rgb * max(cosine ? sg_cosine_integral(l, n) : sg_inner_product(l, kernel), 0.0);
        skipping = skipping || by < min_fraction * vis_sum;
        if (skipping) {
            skipped += e;
            continue;
        }
        float vk = visible(p, n, sg_product(l, kernel));
        shadowed += e * vk;
        vis_sum += vk * by;
        vis_w += by;
    }
    return shadowed + skipped * (vis_w > 0.0 ? vis_sum / vis_w : 1.0);
}

// Diffuse: isg_lobes_shadowed through the clamped cosine of n.
vec3 isg_lobes_diffuse(vec3 p, vec3 n, uint nl, float min_fraction, out vec3 unshadowed) {
    return isg_lobes_shadowed(p, n, nl, min_fraction, sg_clamped_cosine(n), true, unshadowed);
}

// The light the lighting lobes send through the glossy lobe gj (the BRDF's specular SG times the
// cosine), shadowed (returned) and unshadowed (`open`), as luminance: sum_k e_k V_k and sum_k e_k
// over the lighting lobes (e_k: lobe k's inner product with gj), the ISG paper's specular
// visibility (eq. 9, per lighting lobe). A lobe narrower than about 4 degrees (lambda > 256) sees
// nearly constant light: open times its own visible fraction, one traversal instead of one per
// lighting lobe (isg_bunny's shininess-1000 and chess's ivory lobes at 160x120: the same error at
// 1.6-1.8x the time per frame). Where no lighting lobe reaches gj, its own visible fraction with a
// negligible weight (open = 1e-30). One traversal site each for the ISG and the lobes (lavapipe
// compiles every inlined copy of the traversal: callers loop over lobes without unrolling).
float isg_lobes_glossy_light(vec3 p, vec3 n, uint nl, float min_fraction, SG gj, out float open) {
    const vec3 lum = vec3(0.2126, 0.7152, 0.0722);
    bool sharp = gj.lambda > 256.0;
    float shadowed = 0.0;
    if (sharp) {
        vec3 e = vec3(0.0);
        for (uint k = 0u; k < min(nl, 64u); ++k)
            e += lobes[2u * k + 1u].rgb * max(sg_inner_product(sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0), gj), 0.0);
        open = dot(e, lum);
    } else {
        vec3 o;
        shadowed = dot(isg_lobes_shadowed(p, n, nl, min_fraction, gj, false, o), lum);
        open = dot(o, lum);
    }
    if (sharp || !(open > 0.0)) {
        if (!(open > 0.0)) open = 1e-30;
        shadowed = open * visible(p, n, gj);
    }
    return shadowed;
}

// The light-weighted visible share of the glossy lobe gj: isg_lobes_glossy_light's shadowed over
// unshadowed light, as a scalar (luminance) ratio for the material model's glossy term. The
// lobe's own visible fraction (every direction of gj weighted alike) darkened a glossy surface
// whose lobe reaches both a bright sky and a dark occluder below it.
float isg_lobes_glossy_visibility(vec3 p, vec3 n, uint nl, float min_fraction, SG gj) {
    float open;
    float shadowed = isg_lobes_glossy_light(p, n, nl, min_fraction, gj, open);
    return clamp(shadowed / open, 0.0, 1.0);
}

#endif
