// The one material model of penumbra on the GPU: a scene material (`MaterialData` of
// common.glsl, packed by passes/src/scene_gpu.rs) at a surface point, with its texture maps
// applied exactly as the CPU reference does (penumbra_reference::render::brdf_at): the albedo
// map multiplies the albedo, the roughness map's G channel multiplies the roughness, and the
// Blinn-Phong exponent then follows 2 / r^2 - 2; the emission map multiplies the emission, which
// each technique adds to what it shades (material_emission). Every technique fetches its materials through
// `material_at`; a technique that approximates the BRDF (SG lobes, SH transfer, prefiltered
// lookups) builds its approximation from the returned material.
#ifndef PENUMBRA_MATERIAL_GLSL
#define PENUMBRA_MATERIAL_GLSL

// `m` at texture coordinate `uv`; `tex` is the scene's material texture array (repeat, bilinear).
MaterialData material_at(MaterialData m, vec2 uv, sampler2DArray tex) {
    if (m.extra.y >= 0.0) m.albedo_kind.rgb = max(m.albedo_kind.rgb * textureLod(tex, vec3(uv, m.extra.y), 0.0).rgb, vec3(0.0));
    if (m.extra.z >= 0.0) {
        float r = clamp(m.spec_rough.w * textureLod(tex, vec3(uv, m.extra.z), 0.0).g, 0.0, 1.0);
        m.spec_rough.w = r;
        // as for animated roughness: the Phong-type exponents follow 2 / r^2 - 2 (the second
        // Ashikhmin-Shirley exponent keeps its ratio to the first)
        float e = clamp(2.0 / max(r * r, 1e-4) - 2.0, 0.0, 1e6);
        m.extra.w = clamp(m.extra.w * e / max(m.extra.x, 1e-6), 0.0, 1e6);
        m.extra.x = e;
    }
    if (m.emission.w >= 0.0) m.emission.rgb = max(m.emission.rgb * textureLod(tex, vec3(uv, m.emission.w), 0.0).rgb, vec3(0.0));
    return m;
}

// The shading normal n with the material's tangent-space normal map applied at uv (as the
// reference's normal_at): +x along dpdu, +y along dpdv (the surface's position derivatives along
// u and v, any length), z along n; x and y scaled by the map's scale. Applied once, where the
// G-buffer is written (and by mc at its primary hits): every technique shades with the result.
vec3 material_normal(MaterialData m, vec2 uv, sampler2DArray tex, vec3 n, vec3 dpdu, vec3 dpdv) {
    if (m.normal.x < 0.0) return n;
    vec3 t = dpdu - n * dot(n, dpdu);
    if (!(dot(t, t) >= 1e-20)) return n;
    t = normalize(t);
    vec3 b = cross(n, t);
    if (dot(b, dpdv) < 0.0) b = -b;
    vec3 c = textureLod(tex, vec3(uv, m.normal.x), 0.0).rgb * 2.0 - 1.0;
    vec3 nm = t * (c.x * m.normal.y) + b * (c.y * m.normal.y) + n * max(c.z, 1e-3);
    float l2 = dot(nm, nm);
    return l2 > 0.0 ? nm * inversesqrt(l2) : n;
}

// The shading normal n (unit) turned towards the unit direction to the viewer v just as far as
// needed to make n . v at least about 0.01, else n itself: the reference's facing_normal
// (render.rs), which says why. Applied once after material_normal, where the G-buffer is written
// (and by mc at its primary hits, vv where it shades): every technique shades with the result.
vec3 material_facing_normal(vec3 n, vec3 v) {
    const float min_cos = 0.01;
    float c = dot(n, v);
    if (!(c < min_cos)) return n;
    vec3 b = n + v * (min_cos - c);
    float l2 = dot(b, b);
    return l2 > 1e-20 ? b * inversesqrt(l2) : v;
}

// The light a surface reflects towards the eye, `color`, where the eye sees the front of the
// shading hemisphere of the normal n from the unit direction v; else nothing: there the BRDF is
// zero and only emission is seen, the reference's rule (reference/src/render.rs; mc applies it
// through wo.z). Normals that went through material_facing_normal always pass; the test guards
// shading normals that did not.
vec3 material_reflected(vec3 color, vec3 n, vec3 v) {
    return dot(n, v) > 0.0 ? color : vec3(0.0);
}

// The albedo that multiplies albedo / pi x irradiance, the techniques' environment diffuse term,
// for a viewer at n.v = ndv: the material's albedo, except for Ashikhmin-Shirley, whose diffuse
// lobe (the reference's, brdf_ref.glsl: 28 / (23 pi) albedo (1 - F0) (1 - (1 - n.wi / 2)^5)
// (1 - (1 - n.v / 2)^5)) reflects albedo (1 - F0) (1 - (1 - n.v / 2)^5) of uniform light (the
// n.wi factor's cosine-weighted mean is 23 / 28): 11 % less than a Lambertian surface seen
// head-on with F0 = 0.08, 30 % less at 60 degrees. Local lights go through light_brdf, exact.
vec3 material_diffuse_albedo(MaterialData m, float ndv) {
    vec3 a = m.albedo_kind.rgb;
    if (int(m.albedo_kind.w + 0.5) != 3) return a;
    float c = 1.0 - clamp(ndv, 0.0, 1.0) * 0.5;
    float c2 = c * c;
    return a * (vec3(1.0) - clamp(m.spec_rough.rgb, vec3(0.0), vec3(1.0))) * (1.0 - c2 * c2 * c);
}

// The radiance the surface emits towards the eye (after material_at: its map applied). It
// lights nothing else: the reference and every technique compute direct lighting only.
vec3 material_emission(MaterialData m) {
    return m.emission.rgb;
}

// 0 diffuse, 1 Blinn-Phong, 2 Cook-Torrance (GGX), 3 Ashikhmin-Shirley (isotropic).
int material_kind(MaterialData m) { return int(m.albedo_kind.w + 0.5); }

// The perceptual roughness of the specular lobe, for prefiltered-environment lookups and split-sum
// terms: Blinn-Phong's exponent s as sqrt(2 / (s + 2)), else the material's roughness.
float material_roughness(MaterialData m) {
    return clamp(material_kind(m) == 1 ? sqrt(2.0 / (m.extra.x + 2.0)) : m.spec_rough.w, 0.02, 1.0);
}

#endif
