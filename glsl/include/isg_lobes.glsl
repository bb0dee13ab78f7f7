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
// With `own`, one constant lobe of radiance 1 instead of the lighting: the kernel's own visible
// fraction (in every channel; `unshadowed` 1), through the same call of visible(), so that a
// shader that asks for both inlines one traversal (lavapipe compiles every inlined copy).
vec3 isg_lobes_shadowed(vec3 p, vec3 n, uint nl, float min_fraction, SG kernel, bool cosine, bool own, out vec3 unshadowed) {
    nl = own ? 1u : min(nl, 64u);
    float ys[64];
    unshadowed = vec3(0.0);
    for (uint k = 0u; k < nl; ++k) {
        SG l = own ? kernel : sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        vec3 e = own ? vec3(1.0) : lobes[2u * k + 1u].rgb * max(cosine ? sg_cosine_integral(l, n) : sg_inner_product(l, kernel), 0.0);
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
        SG l = own ? kernel : sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0);
        vec3 e = own ? vec3(1.0) : lobes[2u * k + 1u].rgb * max(cosine ? sg_cosine_integral(l, n) : sg_inner_product(l, kernel), 0.0);
        skipping = skipping || by < min_fraction * vis_sum;
        if (skipping) {
            skipped += e;
            continue;
        }
        float vk = visible(p, n, own ? kernel : sg_product(l, kernel));
        shadowed += e * vk;
        vis_sum += vk * by;
        vis_w += by;
    }
    return shadowed + skipped * (vis_w > 0.0 ? vis_sum / vis_w : 1.0);
}

// Diffuse: isg_lobes_shadowed through the clamped cosine of n.
vec3 isg_lobes_diffuse(vec3 p, vec3 n, uint nl, float min_fraction, out vec3 unshadowed) {
    return isg_lobes_shadowed(p, n, nl, min_fraction, sg_clamped_cosine(n), true, false, unshadowed);
}

// The light the lighting lobes send through the glossy lobe gj (the BRDF's specular SG times the
// cosine), shadowed (returned) and unshadowed (`open`), as luminance: sum_k e_k V_k and sum_k e_k
// over the lighting lobes (e_k: lobe k's inner product with gj), the ISG paper's specular
// visibility (eq. 9, per lighting lobe). A lobe narrower than about 4 degrees (lambda > 256) sees
// nearly constant light: open times its own visible fraction, one traversal instead of one per
// lighting lobe (isg_bunny's shininess-1000 and chess's ivory lobes at 160x120: the same error at
// 1.6-1.8x the time per frame). Where no lighting lobe reaches gj, its own visible fraction with a
// negligible weight (open = 1e-30). One call of isg_lobes_shadowed in a loop of its two steps
// (the lighting lobes; the lobe's own fraction): one inlined traversal (lavapipe compiles every
// inlined copy: callers loop over lobes without unrolling).
float isg_lobes_glossy_sharp_open(uint nl, SG gj) {
    vec3 e = vec3(0.0);
    for (uint k = 0u; k < min(nl, 64u); ++k)
        e += lobes[2u * k + 1u].rgb * max(sg_inner_product(sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0), gj), 0.0);
    return dot(e, vec3(0.2126, 0.7152, 0.0722));
}
float isg_lobes_glossy_light(vec3 p, vec3 n, uint nl, float min_fraction, SG gj, out float open) {
    bool sharp = gj.lambda > 256.0;
    float shadowed = 0.0;
    open = sharp ? isg_lobes_glossy_sharp_open(nl, gj) : 0.0;
    for (int step = 0; step < 2; ++step) {
        bool own = step == 1;
        if (own ? !(sharp || !(open > 0.0)) : sharp) continue;
        vec3 o;
        vec3 r = isg_lobes_shadowed(p, n, nl, min_fraction, gj, false, own, o);
        if (own) {
            if (!(open > 0.0)) open = 1e-30;
            shadowed = open * r.x;
        } else {
            shadowed = dot(r, vec3(0.2126, 0.7152, 0.0722));
            open = dot(o, vec3(0.2126, 0.7152, 0.0722));
        }
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
