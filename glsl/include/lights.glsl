// The one local-light model of the GPU techniques (point, spot, sphere and directional lights of
// the scene, `LightData` of common.glsl), without visibility: each technique loops over its light table and
// multiplies by its own visibility. Matches the reference renderer's direct lighting: point and
// spot lights have radiant intensity `power` (W/sr; spots fade by smoothstep between the outer
// and inner cone cosines); a sphere light of emitted radiance `power` and radius r is a point of
// intensity power * pi * r^2 (exact at normal incidence far from it); the participating medium's
// transmittance along the way (light_transmittance); a directional light gives irradiance `power`
// to a surface facing it.
// Needs common.glsl (PI, LightData, MaterialData, light_transmittance).
#ifndef PENUMBRA_LIGHTS_GLSL
#define PENUMBRA_LIGHTS_GLSL

// The distance a directional light (kind 3) is taken to be at: shadow rays and occluder searches
// toward it end there (far beyond any scene penumbra renders; small enough that its square and
// products with scene coordinates stay finite in fp32).
const float LIGHT_FAR = 1.0e7;

// The vector from pos to light l: to its position, or LIGHT_FAR along a directional light's
// reversed direction.
vec3 light_vector(LightData l, vec3 pos) {
    return int(l.pos_kind.w + 0.5) == 3 ? -l.dir_cos_outer.xyz * LIGHT_FAR : l.pos_kind.xyz - pos;
}

// light_incident by the shading normal alone.
vec3 light_incident_shading(LightData l, vec3 pos, vec3 n, out vec3 wi, out float dist, out float ndl) {
    int lk = int(l.pos_kind.w + 0.5);
    if (lk == 3) {
        // directional: irradiance `power` along `dir` from infinitely far (LIGHT_FAR away)
        wi = -l.dir_cos_outer.xyz;
        dist = LIGHT_FAR;
        ndl = dot(n, wi);
        return ndl > 0.0 ? l.power_cos_inner.rgb : vec3(0.0);
    }
    vec3 to_l = l.pos_kind.xyz - pos;
    float d2 = max(dot(to_l, to_l), 1e-8);
    dist = sqrt(d2);
    wi = to_l * inversesqrt(d2);
    ndl = dot(n, wi);
    if (ndl <= 0.0) return vec3(0.0);
    vec3 intensity = l.power_cos_inner.rgb;
    if (lk == 1) {
        float c = dot(-wi, normalize(l.dir_cos_outer.xyz));
        intensity *= smoothstep(l.dir_cos_outer.w, l.power_cos_inner.w, c);
    } else if (lk == 2) {
        intensity *= PI * l.extra.x * l.extra.x;
    }
    return intensity * light_transmittance(l, dist) / d2;
}

// Irradiance-like factor of light l at pos: intensity x transmittance / distance^2 (rgb), with
// the unit direction to the light `wi`, its distance and n . wi. Zero (and ndl <= 0) when the
// light is behind the shading normal n or below the geometric surface ng (the reference's rule:
// such light is blocked by the surface itself; smooth normals over a thin or coarse feature face
// lights their face turns from). Shaders without the face's normal pass n as ng.
vec3 light_incident(LightData l, vec3 pos, vec3 n, vec3 ng, out vec3 wi, out float dist, out float ndl) {
    vec3 e = light_incident_shading(l, pos, n, wi, dist, ndl);
    if (dot(wi, ng) <= 0.0) {
        ndl = 0.0;
        return vec3(0.0);
    }
    return e;
}

#ifdef PENUMBRA_MATERIAL_GLSL
#include "brdf_ref.glsl"
// The BRDF for light from wi towards v (both unit, away from the surface) at a point of shading
// normal n and tangent t: the reference's (brdf_ref.glsl brdf_eval of brdf_from_material, the
// material model's BRDF, in the reference's shading frame brdf_frame(n, t)), with the diffuse
// albedo replaced by `albedo` (a technique that brings the diffuse light another way passes
// vec3(0.0)). A caller without a tangent passes vec3(0.0): Ashikhmin-Shirley is then isotropic at
// the geometric mean of its exponents. (Before, an approximation of its own: Blinn-Phong with a
// Schlick Fresnel rise the reference's has not, GGX with Schlick's k = alpha / 2 masking instead
// of Smith's, Ashikhmin-Shirley as a GGX lobe of a roughness each technique chose differently.)
vec3 light_brdf(vec3 wi, vec3 n, vec3 t, vec3 v, vec3 albedo, MaterialData m) {
    Brdf b = brdf_from_material(m);
    b.albedo = max(albedo, vec3(0.0));
    if (b.kind == 3u && dot(t, t) == 0.0) { b.nu = sqrt(b.nu * b.nv); b.nv = b.nu; }
    mat3 f = brdf_frame(n, t);
    return brdf_eval(b, v * f, wi * f);
}
#endif

// Shadow-ray targets on a sphere light (techniques that trace their local lights' shadows):
// the centre and 8 points on the disk of radius `radius` facing the shading point (two rings at
// 0.45 and 0.9 of the radius, rotated against each other), equally weighted: a soft shadow whose
// penumbra follows the light's size. Returns the k-th target (0 <= k < LIGHT_DISK_POINTS) as a
// vector from the shading point; `to_light` is light_vector's.
const int LIGHT_DISK_POINTS = 9;
// The unit vector at angle a in the plane across unit direction w (the disk's own frame).
vec3 light_disk_offset(vec3 w, float a) {
    vec3 bx = normalize(abs(w.x) < 0.9 ? cross(vec3(1.0, 0.0, 0.0), w) : cross(vec3(0.0, 1.0, 0.0), w));
    vec3 by = cross(w, bx);
    return bx * cos(a) + by * sin(a);
}
vec3 light_disk_target(vec3 to_light, float radius, int k) {
    if (k == 0) return to_light;
    float ring = k <= 4 ? 0.45 : 0.9;
    float a = 1.5707963 * float(k - 1) + (k <= 4 ? 0.0 : 0.7853982);
    return to_light + light_disk_offset(normalize(to_light), a) * (ring * radius);
}

// The order in which a disk's 9 rays are traced: the centre and the outer ring first; where those
// DISK_FIRST rays agree (the light wholly seen or wholly hidden: most pixels), the inner ring is
// not traced. A penumbra, where they disagree, takes all nine.
const int DISK_FIRST = 5;
int disk_ray(int i) { return i == 0 ? 0 : (i <= 4 ? i + 4 : i - 4); }
bool disk_settled(int i, float vis, float cnt) { return i == DISK_FIRST && cnt > 0.0 && (vis == 0.0 || vis == cnt); }

#endif
