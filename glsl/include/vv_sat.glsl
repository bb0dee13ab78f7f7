// Vectorized-visibility radiance integration with summed-area tables: the GLSL mirror of
// penumbra_math::vv_sat (same arc splitting, same interpolation factor, eq. 9-12).
//
// SAT image (RGBA32F, width W + 1, height 3 (H + 1)): channel k (x, y, z of l L_e, rgb) is the
// block of rows k (H + 1) .. k (H + 1) + H; corner (i, j) = integral over texels x < i, y < j.
// Loops of unit directions are in *map space* (world directions rotated by -rotation about +Y);
// a loop counter-clockwise seen from the centre adds its interior, clockwise subtracts it.
#ifndef PENUMBRA_VV_SAT_GLSL
#define PENUMBRA_VV_SAT_GLSL

#define VV_MAX_DPHI (PI / 8.0)

struct VvAcc {
    vec3 m[3];    // integral of x, y, z times L_e (rgb each)
    float dphi;   // net longitude travelled
};

void vv_acc_init(out VvAcc a) {
    a.m[0] = vec3(0.0);
    a.m[1] = vec3(0.0);
    a.m[2] = vec3(0.0);
    a.dphi = 0.0;
}

vec3 vv_corner(sampler2D sat, ivec2 size, int k, int x, int y) {
    return texelFetch(sat, ivec2(x, k * (size.y + 1) + y), 0).rgb;
}

// SAT at (phi, theta), bilinear between corners.
void vv_lookup(sampler2D sat, ivec2 size, float phi, float theta, out vec3 m[3]) {
    float fx = clamp(phi / (2.0 * PI) * float(size.x), 0.0, float(size.x));
    float fy = clamp(theta / PI * float(size.y), 0.0, float(size.y));
    int x0 = min(int(floor(fx)), size.x - 1);
    int y0 = min(int(floor(fy)), size.y - 1);
    float tx = fx - float(x0), ty = fy - float(y0);
    for (int k = 0; k < 3; k++) {
        m[k] = vv_corner(sat, size, k, x0, y0) * ((1.0 - tx) * (1.0 - ty)) + vv_corner(sat, size, k, x0 + 1, y0) * (tx * (1.0 - ty))
             + vv_corner(sat, size, k, x0, y0 + 1) * ((1.0 - tx) * ty) + vv_corner(sat, size, k, x0 + 1, y0 + 1) * (tx * ty);
    }
}

vec2 vv_angles(vec3 d) {
    float theta = acos(clamp(d.y, -1.0, 1.0));
    float phi = atan(d.x, -d.z);
    if (phi < 0.0) phi += 2.0 * PI;
    return vec2(phi, theta);
}

float vv_wrap_pi(float a) {
    if (a > PI) a -= 2.0 * PI;
    if (a <= -PI) a += 2.0 * PI;
    return a;
}

float vv_lum(vec3 c) {
    return dot(c, vec3(0.2126, 0.7152, 0.0722));
}

// One piece monotone in theta (eq. 10-11).
void vv_piece(sampler2D sat, ivec2 size, float alpha, float pa, float ta, float pb, float tb, vec3 a, vec3 b, inout VvAcc acc) {
    if (abs(pb - pa) < 1e-7) return;
    float tmin = min(ta, tb), tmax = max(ta, tb);
    vec3 l0[3], l1[3], l2[3], l3[3];
    vv_lookup(sat, size, pb, tmin, l0);
    vv_lookup(sat, size, pa, tmin, l1);
    vv_lookup(sat, size, pb, tmax, l2);
    vv_lookup(sat, size, pa, tmax, l3);
    vec3 smin[3], bx[3];
    for (int k = 0; k < 3; k++) {
        smin[k] = l0[k] - l1[k];
        bx[k] = (l2[k] - l3[k]) - smin[k];
    }
    float s = sign(pb - pa);
    vec3 c = vec3(vv_lum(bx[0]), vv_lum(bx[1]), vv_lum(bx[2])) * s;
    float f = 0.5;
    vec3 m = cross(a, b);
    float ml = length(m);
    if (length(c) > 1e-30 && tmax - tmin > 1e-7 && ml > 1e-12) {
        vec3 mh = m / ml;
        float side = asin(clamp(dot(normalize(c), mh), -1.0, 1.0)) * (mh.y >= 0.0 ? 1.0 : -1.0);
        f = 0.5 + 0.5 * tanh(clamp(alpha * side * float(size.y) / PI, -20.0, 20.0));
    }
    for (int k = 0; k < 3; k++) acc.m[k] += smin[k] + f * bx[k];
}

// A sub-arc with small longitude span: seam split, then the piece.
void vv_seg(sampler2D sat, ivec2 size, float alpha, vec3 a, vec3 b, inout VvAcc acc) {
    vec2 A = vv_angles(a), B = vv_angles(b);
    if (sin(A.y) < 1e-6) A.x = B.x;
    if (sin(B.y) < 1e-6) B.x = A.x;
    float d = vv_wrap_pi(B.x - A.x);
    acc.dphi += d;
    float e = A.x + d;
    if (e > 2.0 * PI || e < 0.0) {
        float t = a.x / (a.x - b.x);
        vec3 p = normalize(a + (b - a) * t);
        float tp = vv_angles(p).y;
        float sa = d > 0.0 ? 2.0 * PI : 0.0;
        float sb = d > 0.0 ? 0.0 : 2.0 * PI;
        vv_piece(sat, size, alpha, A.x, A.y, sa, tp, a, p, acc);
        vv_piece(sat, size, alpha, sb, tp, sb + (e - sa), B.y, p, b, acc);
    } else {
        vv_piece(sat, size, alpha, A.x, A.y, e, B.y, a, b, acc);
    }
}

// A sub-arc monotone in latitude: at most VV_MAX_DPHI of longitude per piece.
void vv_sub(sampler2D sat, ivec2 size, float alpha, vec3 a, vec3 b, inout VvAcc acc) {
    vec2 A = vv_angles(a), B = vv_angles(b);
    if (sin(A.y) < 1e-6) A.x = B.x;
    if (sin(B.y) < 1e-6) B.x = A.x;
    float d = abs(vv_wrap_pi(B.x - A.x));
    int n = clamp(int(ceil(d / VV_MAX_DPHI)), 1, 16);
    vec3 prev = a;
    for (int i = 1; i <= n; i++) {
        vec3 q = i == n ? b : normalize(mix(a, b, float(i) / float(n)));
        vv_seg(sat, size, alpha, prev, q, acc);
        prev = q;
    }
}

// One great arc a -> b of a loop (eq. 12 term), split at its latitude extremum.
void vv_arc(sampler2D sat, ivec2 size, float alpha, vec3 a, vec3 b, inout VvAcc acc) {
    vec3 m = cross(a, b);
    float ml = length(m);
    if (ml < 1e-7) return;
    vec3 mh = m / ml;
    vec3 top = vec3(0.0, 1.0, 0.0) - mh * mh.y;
    if (length(top) > 1e-7) {
        top = normalize(top);
        for (int s = 0; s < 2; s++) {
            vec3 p = s == 0 ? top : -top;
            if (dot(cross(a, p), mh) > 1e-7 && dot(cross(p, b), mh) > 1e-7) {
                vv_sub(sat, size, alpha, a, p, acc);
                vv_sub(sat, size, alpha, p, b, acc);
                return;
            }
        }
    }
    vv_sub(sat, size, alpha, a, b, acc);
}

// Cap axis moved off a pole-through circle (penumbra_math::vv_sat::nudge_axis; 2e-3 rad, above
// fp32's angular resolution at a pole).
vec3 vv_nudge(vec3 axis, float cos_r) {
    if (abs(axis.y - cos_r) < 1e-3 || abs(-axis.y - cos_r) < 1e-3) {
        return normalize(axis + vec3(0.0, axis.y >= 0.0 ? 2e-3 : -2e-3, 0.0));
    }
    return axis;
}

// Orthonormal u, v with cross(u, v) = a (as penumbra_math::vv_sat::basis).
void vv_basis(vec3 a, out vec3 u, out vec3 v) {
    vec3 t = abs(a.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    u = normalize(cross(t, a));
    v = cross(a, u);
}

// Adds the hemisphere of the (nudged) normal as a positive loop of `steps` arcs.
void vv_add_hemisphere(sampler2D sat, ivec2 size, float alpha, vec3 n, int steps, inout VvAcc acc) {
    vec3 u, v;
    vv_basis(n, u, v);
    vec3 first = u;
    vec3 prev = first;
    for (int i = 1; i <= steps; i++) {
        float ang = -2.0 * PI * float(i) / float(steps);
        vec3 q = i == steps ? first : normalize(u * cos(ang) + v * sin(ang));
        vv_arc(sat, size, alpha, prev, q, acc);
        prev = q;
    }
}

// Finishes the loop sum: the whole-sphere correction when the south pole is inside the
// hemisphere of n (winding(N) = 0 then), and returns n . integral (rgb).
vec3 vv_finish(sampler2D sat, ivec2 size, vec3 n_nudged, VvAcc acc) {
    if (!(n_nudged.y > 0.0)) {
        float w = round(acc.dphi / (2.0 * PI));
        for (int k = 0; k < 3; k++) acc.m[k] -= w * vv_corner(sat, size, k, size.x, size.y);
    }
    return acc.m[0] * n_nudged.x + acc.m[1] * n_nudged.y + acc.m[2] * n_nudged.z;
}

// Eq. 3 with the hemisphere clamp of penumbra_math::vv (synth_dir + clamp_to_hemisphere).
vec3 vv_synth(vec4 q, vec3 s, vec3 n, vec3 fallback) {
    vec3 d = q.xyz - q.w * s;
    float l = length(d);
    d = l > 1e-12 ? d / l : fallback;
    float c = dot(d, n);
    if (c < 0.0) {
        vec3 t = d - c * n;
        float tl = length(t);
        vec3 u, v;
        vv_basis(n, u, v);
        d = tl > 1e-6 ? t / tl : u;
    }
    return d;
}

// World direction to map space (rotation by -rotation about +Y).
vec3 vv_to_map(vec3 d, vec2 cs) {
    return vec3(cs.x * d.x - cs.y * d.z, d.y, cs.y * d.x + cs.x * d.z);
}

#endif
