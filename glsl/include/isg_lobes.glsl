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

// The glossy visibility (isg_glossy_*): the light the lighting lobes send through the glossy
// lobe gj (the BRDF's specular SG times the cosine), shadowed and unshadowed (`open`), as
// luminance: sum_k e_k V_k and sum_k e_k over the lighting lobes (e_k: lobe k's inner product
// with gj), the ISG paper's specular visibility (eq. 9, per lighting lobe); their ratio weights
// the material model's glossy term, since the lobe's own visible fraction (every direction of gj
// weighted alike) darkened a glossy surface whose lobe reaches both a bright sky and a dark
// occluder below it. A lobe narrower than about 4 degrees (lambda > 256) sees nearly constant
// light: open times its own visible fraction, one traversal instead of one per lighting lobe
// (isg_bunny's shininess-1000 and chess's ivory lobes at 160x120: the same error at 1.6-1.8x the
// time per frame). Where no lighting lobe reaches gj, its own visible fraction with a negligible
// weight (open = 1e-30). Callers run it as two steps of a loop around their one call of
// isg_lobes_shadowed (step 0 the lighting lobes, step 1 gj's own fraction, `own`), with the
// diffuse query and every other glossy lobe: one inlined traversal per shader (lavapipe compiles
// every inlined copy; isg_shade.glsl's four had taken its first compile to 46 s).
//
// open before the steps: for a sharp lobe the lighting's luminance through it (no traversal).
float isg_glossy_open(uint nl, SG gj) {
    if (!(gj.lambda > 256.0)) return 0.0;
    vec3 e = vec3(0.0);
    for (uint k = 0u; k < min(nl, 64u); ++k)
        e += lobes[2u * k + 1u].rgb * max(sg_inner_product(sg_make(lobes[2u * k].xyz, lobes[2u * k].w, 1.0), gj), 0.0);
    return dot(e, vec3(0.2126, 0.7152, 0.0722));
}
// Whether step `step` runs for gj.
bool isg_glossy_step(int step, SG gj, float open) {
    bool sharp = gj.lambda > 256.0;
    return step == 0 ? !sharp : (sharp || !(open > 0.0));
}
// Folds step `step`'s isg_lobes_shadowed result (r, its unshadowed o) into shadowed and open.
void isg_glossy_fold(int step, vec3 r, vec3 o, inout float shadowed, inout float open) {
    const vec3 lum = vec3(0.2126, 0.7152, 0.0722);
    if (step == 1) {
        if (!(open > 0.0)) open = 1e-30;
        shadowed = open * r.x;
    } else {
        shadowed = dot(r, lum);
        open = dot(o, lum);
    }
}

#endif
