// BRDFs of penumbra_reference::brdf (evaluation, pdf and sampling), local frame: n = +Z,
// tangent = +X. Shared by mc.comp and shadowmaps/shadowmaps_shade.comp; `brdf_from_material` builds one from a
// material of material.glsl (include that first).
#ifndef PENUMBRA_BRDF_REF_GLSL
#define PENUMBRA_BRDF_REF_GLSL
#ifndef M_PI
#define M_PI 3.14159265358979323846
#define M_TAU 6.28318530717958647692
#endif

struct Brdf { uint kind; vec3 albedo; vec3 spec; float alpha; float nu; float nv; float p_spec; };

vec3 schlick(vec3 f0, float c) { float m = clamp(1.0 - c, 0.0, 1.0); float m2 = m * m; return f0 + (1.0 - f0) * (m2 * m2 * m); }
float ggx_d(float a, float ch) { if (ch <= 0.0) return 0.0; float a2 = a * a; float d = ch * ch * (a2 - 1.0) + 1.0; return a2 / (M_PI * d * d); }
float ggx_g1(float a, float c) { if (c <= 0.0) return 0.0; float a2 = a * a; return 2.0 * c / (c + sqrt(a2 + (1.0 - a2) * c * c)); }
float as_norm(float nu, float nv) { return sqrt((nu + 1.0) * (nv + 1.0)); }
float as_lobe(float nu, float nv, vec3 h) {
    if (h.z <= 0.0) return 0.0;
    float s2 = h.x * h.x + h.y * h.y;
    float e = s2 > 1e-12 ? (nu * h.x * h.x + nv * h.y * h.y) / s2 : 0.5 * (nu + nv);
    return pow(h.z, e);
}

// The reference's shading frame (penumbra_reference::sampling::Frame::new) as columns (x, y, n):
// x the tangent hint t made orthogonal to n (anisotropic lobes: Ashikhmin-Shirley's nu runs
// along it), y = n x x; where t is unusable (zero, or along n) Duff et al. 2017's branchless
// basis of n. brdf_eval, brdf_pdf and brdf_sample work in it: local = transpose(frame) * world.
mat3 brdf_frame(vec3 n, vec3 t) {
    vec3 x = t - n * dot(n, t);
    if (dot(x, x) > 1e-12) {
        x = normalize(x);
    } else {
        float s = n.z >= 0.0 ? 1.0 : -1.0;
        float a = -1.0 / (s + n.z);
        float bb = n.x * n.y * a;
        x = vec3(1.0 + s * n.x * n.x * a, s * bb, -s * n.x);
    }
    return mat3(x, cross(n, x), n);
}

vec3 brdf_eval(Brdf b, vec3 wo, vec3 wi) {
    float co = wo.z, ci = wi.z;
    if (co <= 0.0 || ci <= 0.0) return vec3(0.0);
    vec3 hs = wo + wi;
    if (dot(hs, hs) == 0.0) return vec3(0.0);
    vec3 h = normalize(hs);
    if (b.kind == 0u) return b.albedo / M_PI;
    if (b.kind == 1u) return b.albedo / M_PI + b.spec * ((b.nu + 2.0) / (8.0 * M_PI) * pow(max(h.z, 0.0), b.nu));
    if (b.kind == 2u) {
        float d = ggx_d(b.alpha, h.z);
        float g = ggx_g1(b.alpha, ci) * ggx_g1(b.alpha, co);
        return b.albedo / M_PI + schlick(b.spec, dot(wi, h)) * (d * g / (4.0 * ci * co));
    }
    float hdk = max(dot(wi, h), 1e-6);
    float spec = as_norm(b.nu, b.nv) / (8.0 * M_PI) * as_lobe(b.nu, b.nv, h) / (hdk * max(ci, co));
    vec3 f = schlick(b.spec, hdk);
    float mi = 1.0 - ci / 2.0, mo = 1.0 - co / 2.0;
    float pi5 = 1.0 - mi * mi * mi * mi * mi, po5 = 1.0 - mo * mo * mo * mo * mo;
    vec3 diff = b.albedo * (1.0 - b.spec) * (28.0 / (23.0 * M_PI) * pi5 * po5);
    return diff + f * spec;
}

float brdf_pdf(Brdf b, vec3 wo, vec3 wi) {
    if (wo.z <= 0.0 || wi.z <= 0.0) return 0.0;
    float pd = wi.z / M_PI;
    if (b.p_spec <= 0.0) return pd;
    vec3 hs = wo + wi;
    vec3 h = dot(hs, hs) > 0.0 ? normalize(hs) : vec3(0.0);
    float odh = dot(wo, h);
    if (odh <= 0.0) return (1.0 - b.p_spec) * pd;
    float ph = 0.0;
    if (b.kind == 1u) ph = (b.nu + 2.0) / M_TAU * pow(max(h.z, 0.0), b.nu + 1.0);
    else if (b.kind == 2u) ph = ggx_d(b.alpha, h.z) * h.z;
    else if (b.kind == 3u) ph = as_norm(b.nu, b.nv) / M_TAU * as_lobe(b.nu, b.nv, h);
    return (1.0 - b.p_spec) * pd + b.p_spec * ph / (4.0 * odh);
}

vec3 spherical(float cos_t, float phi) { float s = sqrt(max(1.0 - cos_t * cos_t, 0.0)); return vec3(s * cos(phi), s * sin(phi), cos_t); }

bool brdf_sample(Brdf b, vec3 wo, float ul, vec2 u, out vec3 wi) {
    if (wo.z <= 0.0) return false;
    if (ul >= b.p_spec) {
        float r = sqrt(u.x), phi = M_TAU * u.y;
        wi = vec3(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u.x, 0.0)));
        return wi.z > 0.0;
    }
    vec3 h;
    if (b.kind == 0u) return false;
    if (b.kind == 1u) {
        h = spherical(pow(1.0 - u.x, 1.0 / (b.nu + 2.0)), M_TAU * u.y);
    } else if (b.kind == 2u) {
        float a2 = b.alpha * b.alpha;
        float cos2 = (1.0 - u.x) / (1.0 + (a2 - 1.0) * u.x);
        h = spherical(sqrt(clamp(cos2, 0.0, 1.0)), M_TAU * u.y);
    } else {
        float r = sqrt((b.nu + 1.0) / (b.nv + 1.0));
        float a = u.y, phi;
        if (a < 0.25) phi = atan(r * tan(0.5 * M_PI * (4.0 * a)));
        else if (a < 0.5) phi = M_PI - atan(r * tan(0.5 * M_PI * (4.0 * (0.5 - a))));
        else if (a < 0.75) phi = M_PI + atan(r * tan(0.5 * M_PI * (4.0 * (a - 0.5))));
        else phi = M_TAU - atan(r * tan(0.5 * M_PI * (4.0 * (1.0 - a))));
        float s = sin(phi), c = cos(phi);
        float e = b.nu * c * c + b.nv * s * s;
        h = spherical(pow(1.0 - u.x, 1.0 / (e + 1.0)), phi);
    }
    float odh = dot(wo, h);
    wi = 2.0 * odh * h - wo;
    if (!(wi.z > 0.0 && odh > 0.0)) return false;
    wi = normalize(wi);
    return true;
}

#ifdef PENUMBRA_MATERIAL_GLSL
// The BRDF of a material of the one material model (material.glsl's `material_at`, textures
// applied), as penumbra_reference::brdf::Brdf::new builds it: GGX alpha = r^2 (>= 1e-3),
// exponents nu = the shininess, nv = the second Ashikhmin-Shirley exponent, specular sampling probability from the lobes' luminance.
Brdf brdf_from_material(MaterialData m) {
    Brdf b;
    b.kind = uint(clamp(material_kind(m), 0, 3));
    b.albedo = max(m.albedo_kind.rgb, vec3(0.0));
    b.spec = clamp(m.spec_rough.rgb, vec3(0.0), vec3(1.0));
    float r = clamp(m.spec_rough.w, 0.0, 1.0);
    b.alpha = max(r * r, 1e-3);
    b.nu = clamp(m.extra.x, 0.0, 1e6);
    b.nv = clamp(m.extra.w, 0.0, 1e6);
    float ld = dot(b.albedo, vec3(0.2126, 0.7152, 0.0722)), ls = dot(b.spec, vec3(0.2126, 0.7152, 0.0722));
    b.p_spec = b.kind == 0u ? 0.0 : (ls <= 0.0 ? 0.0 : (ld <= 0.0 ? 1.0 : clamp(ls / (ld + ls), 0.05, 0.95)));
    return b;
}
#endif

#endif
