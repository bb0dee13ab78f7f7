// Spherical Gaussians (SGs), f32 mirror of penumbra_math::sg::Sg32 (same formulas; see the
// Rust module docs for derivations and measured errors).
//
//   G(w; p, lambda, mu) = mu * exp(lambda * (dot(p, w) - 1))
//
// p: unit lobe axis, lambda >= 0: sharpness (angular std. dev. ~ 1/sqrt(lambda) rad),
// mu: amplitude (value on the axis). For RGB lobes use a scalar SG with mu = 1 and multiply the
// result by the RGB amplitude. Stable for lambda in [0, 1e5]: exponents are combined before
// exp(), exp(lambda) is never formed, 1 - exp(-x) uses an expm1 polynomial near 0, and
// dot(p, w) - 1 is computed as -|p - w|^2 / 2 (exact for unit vectors).
//
// Self-contained: needs no other include. Everything is prefixed sg_ / SG_.
#ifndef PENUMBRA_SG_GLSL
#define PENUMBRA_SG_GLSL

const float SG_PI = 3.14159265358979323846;

// Wang et al. 2009 clamped-cosine fit (relative L2 error 17.7% over the sphere; it is the
// L2-optimal single lobe to 1%).
const float SG_COS_LAMBDA = 2.133;
const float SG_COS_MU = 1.170;

struct SG {
    vec3 axis;    // unit lobe axis
    float lambda; // sharpness >= 0
    float mu;     // amplitude
};

SG sg_make(vec3 axis, float lambda, float mu) {
    SG g;
    float l2 = dot(axis, axis);
    g.axis = l2 > 0.0 ? axis * inversesqrt(l2) : vec3(0.0, 0.0, 1.0);
    g.lambda = max(lambda, 0.0);
    g.mu = mu;
    return g;
}

// exp(x) - 1 without cancellation near 0 (Taylor series for |x| < 0.5, ~1 ulp).
float sg_expm1(float x) {
    if (abs(x) < 0.5) {
        return x * (1.0 + x * (1.0 / 2.0 + x * (1.0 / 6.0 + x * (1.0 / 24.0 + x * (1.0 / 120.0
            + x * (1.0 / 720.0 + x * (1.0 / 5040.0 + x * (1.0 / 40320.0))))))));
    }
    return exp(x) - 1.0;
}

// (1 - exp(-x)) / x for x >= 0, limit 1 at x = 0.
float sg_one_minus_exp_neg_over_x(float x) {
    if (x < 1e-4) {
        return 1.0 - 0.5 * x;
    }
    return -sg_expm1(-x) / x;
}

// erf: odd Taylor series for |x| < 0.5 (relative accuracy near 0), Abramowitz & Stegun 7.1.26
// otherwise (absolute error < 1.5e-7).
float sg_erf(float x) {
    float a = abs(x);
    float r;
    if (a < 0.5) {
        float x2 = a * a;
        r = 1.1283791670955126 * a * (1.0 + x2 * (-1.0 / 3.0 + x2 * (1.0 / 10.0 + x2 * (-1.0 / 42.0
            + x2 * (1.0 / 216.0 + x2 * (-1.0 / 1320.0))))));
    } else {
        float t = 1.0 / (1.0 + 0.3275911 * a);
        float poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
        r = 1.0 - poly * exp(-a * a);
    }
    return x < 0.0 ? -r : r;
}

// Value at unit direction w.
float sg_eval(SG g, vec3 w) {
    vec3 d = g.axis - w;
    return g.mu * exp(-0.5 * g.lambda * dot(d, d));
}

// Product of two SGs as one SG (exact). lm - l1 - l2 = -l1 l2 |p1 - p2|^2 / (lm + l1 + l2) <= 0.
// Opposite lobes of equal sharpness give lambda = 0 (constant) and keep a's axis.
SG sg_product(SG a, SG b) {
    vec3 u = a.axis * a.lambda + b.axis * b.lambda;
    float lm = length(u);
    vec3 d = a.axis - b.axis;
    float denom = lm + a.lambda + b.lambda;
    float log_scale = denom > 0.0 ? -a.lambda * b.lambda * dot(d, d) / denom : 0.0;
    SG r;
    r.axis = lm > 0.0 ? u / lm : a.axis;
    r.lambda = lm;
    r.mu = a.mu * b.mu * exp(log_scale);
    return r;
}

// Integral over the sphere: 2 pi mu (1 - exp(-2 lambda)) / lambda (4 pi mu at lambda = 0).
float sg_sphere_integral(SG g) {
    return 4.0 * SG_PI * g.mu * sg_one_minus_exp_neg_over_x(2.0 * g.lambda);
}

// Inner product int G1 G2 over the sphere (exact, exponents combined).
float sg_inner_product(SG a, SG b) {
    vec3 u = a.axis * a.lambda + b.axis * b.lambda;
    float lm = length(u);
    vec3 d = a.axis - b.axis;
    float denom = lm + a.lambda + b.lambda;
    float log_scale = denom > 0.0 ? -a.lambda * b.lambda * dot(d, d) / denom : 0.0;
    return 4.0 * SG_PI * a.mu * b.mu * exp(log_scale) * sg_one_minus_exp_neg_over_x(2.0 * lm);
}

// Integral over the hemisphere dot(n, w) > 0 (n unit), Tokuyoshi 2022 approximation:
// lerp between the exact lower (axis = -n) and upper (axis = n) integrals with factor
// 0.5 + 0.5 erf(t c) / erf(t). Exact at c = -1, 0, 1 and lambda -> 0; absolute error <= 0.44% of
// the sphere integral, relative error <= 2.5% where the result is >= 10% of the sphere integral.
float sg_hemisphere_integral(SG g, vec3 n) {
    float l = g.lambda;
    float c = clamp(dot(g.axis, n), -1.0, 1.0);
    float t = l * sqrt((0.5 * l + 0.6517328826907056) / ((l + 1.3418280033141288) * l + 7.221668779895671));
    float et = sg_erf(t);
    float f = et > 0.0 ? clamp(0.5 + 0.5 * sg_erf(t * c) / et, 0.0, 1.0) : 0.5 + 0.5 * c;
    float e = exp(-l);
    return 2.0 * SG_PI * g.mu * (e + (1.0 - e) * f) * sg_one_minus_exp_neg_over_x(l);
}

// SG approximation of the clamped cosine max(0, dot(n, w)) (Wang et al. 2009).
SG sg_clamped_cosine(vec3 n) {
    return sg_make(n, SG_COS_LAMBDA, SG_COS_MU);
}

// Mean of max(0, u + v cos(phi)) over phi uniform, v >= 0.
float sg_clamped_mean(float u, float v) {
    if (v <= abs(u)) return max(u, 0.0);
    float q = clamp(-u / v, -1.0, 1.0);
    return (u * acos(q) + v * sqrt(max(1.0 - q * q, 0.0))) / SG_PI;
}

// Irradiance int G(w) max(0, dot(n, w)) dw of one lobe: its sphere integral times the expected
// clamped cosine under the lobe as a von Mises-Fisher distribution (8-point midpoint rule in the
// CDF of t = dot(w, axis), closed form over the azimuth). Mirrors
// penumbra_math::sg::cosine_irradiance (within 2% of the lobe's normal-incidence irradiance at
// every sharpness; the clamped-cosine SG product was 14% low 48 degrees off a sharp light).
float sg_cosine_integral(SG g, vec3 n) {
    float l = max(g.lambda, 1e-3);
    float c = clamp(dot(g.axis, n), -1.0, 1.0);
    float sc = sqrt(max(1.0 - c * c, 0.0));
    float e2 = exp(-2.0 * l);
    float mean = 0.0;
    for (int i = 0; i < 8; ++i) {
        float s = (float(i) + 0.5) / 8.0;
        float t = clamp(1.0 + log(s * (1.0 - e2) + e2) / l, -1.0, 1.0);
        mean += sg_clamped_mean(c * t, sc * sqrt(max(1.0 - t * t, 0.0)));
    }
    return sg_sphere_integral(g) * mean / 8.0;
}

// Smith G1 of the GGX distribution with width alpha at cosine c (0 at and below the horizon).
float sg_smith_g1(float alpha, float c) {
    if (c <= 0.0) return 0.0;
    float a2 = alpha * alpha;
    return 2.0 * c / (c + sqrt(a2 + (1.0 - a2) * c * c));
}

// The specular BRDF as one SG lobe about the mirror direction r = reflect(-v, n) (the warp of
// Wang et al. 2009), mirrored by penumbra_math::brdf::{BlinnPhong, CookTorrance}::sg_warp.
// kind 1 = normalized Blinn-Phong with exponent `shininess` (amp = f0 = specular colour);
// otherwise Cook-Torrance with Beckmann width m = roughness^2 (clamped to >= 1e-3), the
// remaining factors F G / (4 cos_i cos_o) taken at the lobe axis, with Schlick F (f0) and the
// separable Smith-GGX G = G1(n.v) G1(n.r) (alpha = m). Smith's G goes to 0 at grazing view, so
// the amplitude stays bounded (about 1 / (m^2 pi m^2)) instead of growing as 1 / (n.v)^2: the
// V-cavity G equals 1 at the axis and made single-pixel fireflies at silhouettes.
// ndv is clamped to >= 1e-4 by the caller. Returns the lobe; `amp` multiplies it.
SG sg_specular_lobe(int kind, vec3 n, vec3 v, float ndv, float shininess, float roughness, vec3 f0,
                    out vec3 amp) {
    vec3 r = reflect(-v, n);
    if (kind == 1) {
        float s = max(shininess, 0.0);
        amp = f0;
        return sg_make(r, s / (4.0 * ndv), (s + 2.0) / (8.0 * SG_PI));
    }
    float m = max(roughness * roughness, 1e-3);
    float m2 = m * m;
    float rz = max(dot(r, n), 1e-4);
    float geo = sg_smith_g1(m, ndv) * sg_smith_g1(m, rz);
    amp = f0 + (1.0 - f0) * pow(1.0 - ndv, 5.0);
    return sg_make(r, 2.0 / m2 / (4.0 * ndv), geo / (4.0 * rz * ndv) / (SG_PI * m2));
}

// Ashikhmin-Shirley's specular lobe as SG_AS_LOBES = 7 SGs (the ISG paper's J = 7 for this
// BRDF), built in closed form per point, so that roughness maps and animated exponents need no
// table. Near the normal the lobe's half-vector factor (n.h)^((nu hx^2 + nv hy^2) / (1 - hz^2))
// is the anisotropic Gaussian exp(-(nu sx^2 + nv sy^2) / 2) of the half vector's slopes s. Along
// its wide direction (the smaller exponent) it is the narrow Gaussian convolved with a Gaussian
// of variance 1 / n_wide - 1 / n_narrow, and 7-point Gauss-Hermite quadrature of that convolution
// gives seven lobes of the narrow width (sharpness n_narrow about their half vectors) spread
// along the wide direction with the quadrature's weights times sqrt(n_narrow / n_wide / pi).
// Each is warped to incident directions as the one-lobe warp is (Wang et al. 2009: axis the
// mirror of v about the lobe's half vector h_k, sharpness n_narrow / (4 v.h_k)) and weighted by
// the BRDF's remaining factors at its centre: sqrt((nu + 1)(nv + 1)) / (8 pi) / (h.v max(n.wi,
// n.v)) times Schlick's Fresnel. Isotropic exponents put the seven on one axis with weights
// summing to one lobe's. `frame` is the shading frame (brdf_ref.glsl brdf_frame: x along the
// tangent, nu's direction; z the normal), v the unit direction to the eye. Lobes come back in
// world space with amplitude 1 and their rgb weights in w; a lobe whose centre lies below the
// horizon has weight 0. (math/src/brdf.rs AshikhminShirley::sg7_hermite is the same on the CPU.)
const int SG_AS_LOBES = 7;
void sg_as_lobes(mat3 frame, vec3 v, float nu, float nv, vec3 f0, out SG g[SG_AS_LOBES], out vec3 w[SG_AS_LOBES]) {
    const float xi[7] = float[7](-2.651961356835233, -1.673551628767471, -0.816287882858965, 0.0,
                                 0.816287882858965, 1.673551628767471, 2.651961356835233);
    const float wt[7] = float[7](0.000971781245099520, 0.0545155828191270, 0.425607252610128, 0.810264617556807,
                                 0.425607252610128, 0.0545155828191270, 0.000971781245099520);
    vec3 wo = v * frame;
    nu = clamp(nu, 1e-3, 1e6);
    nv = clamp(nv, 1e-3, 1e6);
    bool x_wide = nu <= nv;
    float n_wide = min(nu, nv), n_narrow = max(nu, nv);
    float sp = sqrt(max(1.0 / n_wide - 1.0 / n_narrow, 0.0)) * 1.4142135623730951;
    float c = sqrt(n_narrow / n_wide / SG_PI) * sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * SG_PI);
    for (int k = 0; k < SG_AS_LOBES; ++k) {
        float s = sp * xi[k];
        vec3 h = normalize(x_wide ? vec3(s, 0.0, 1.0) : vec3(0.0, s, 1.0));
        float vh = dot(wo, h);
        vec3 wi = 2.0 * vh * h - wo;
        g[k] = sg_make(frame * wi, n_narrow / (4.0 * max(vh, 1e-4)), 1.0);
        if (!(vh > 0.0 && wi.z > 0.0 && wo.z > 0.0)) {
            w[k] = vec3(0.0);
            continue;
        }
        float m = 1.0 - vh, m2 = m * m;
        vec3 fresnel = f0 + (1.0 - f0) * (m2 * m2 * m);
        w[k] = fresnel * (c * wt[k] / (vh * max(wi.z, wo.z)));
    }
}

#endif // PENUMBRA_SG_GLSL
