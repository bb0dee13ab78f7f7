// Vectorized-visibility radiance integration with summed-area tables: the GLSL mirror of
// penumbra_math::vv_sat (same arc splitting, same interpolation factor, eq. 9-12).
//
// SAT image (RGBA32F, width W + 1, height 4 (H + 1)): channel k (x, y, z of l L_e, then L_e;
// rgb) is the block of rows k (H + 1) .. k (H + 1) + H; corner (i, j) = integral over texels
// x < i, y < j. Diffuse sums use the first 3 channels (VvAcc.nk = 3), the specular cap ratio
// (eq. 15-16) all 4.
// Loops of unit directions are in *map space* (world directions rotated by -rotation about +Y);
// a loop counter-clockwise seen from the centre adds its interior, clockwise subtracts it.
#ifndef PENUMBRA_VV_SAT_GLSL
#define PENUMBRA_VV_SAT_GLSL

#define VV_MAX_DPHI (PI / 8.0)

struct VvAcc {
    vec3 m[4];    // integral of x, y, z (and 1) times L_e (rgb each)
    float dphi;   // net longitude travelled
    int nk;       // channels accumulated: 3 (diffuse) or 4 (cap-weighted, eq. 15-16)
};

void vv_acc_init(out VvAcc a) {
    a.m[0] = vec3(0.0);
    a.m[1] = vec3(0.0);
    a.m[2] = vec3(0.0);
    a.m[3] = vec3(0.0);
    a.dphi = 0.0;
    a.nk = 3;
}

void vv_acc_init4(out VvAcc a) {
    vv_acc_init(a);
    a.nk = 4;
}

vec3 vv_corner(sampler2D sat, ivec2 size, int k, int x, int y) {
    return texelFetch(sat, ivec2(x, k * (size.y + 1) + y), 0).rgb;
}

// SAT at (phi, theta), bilinear between corners.
void vv_lookup(sampler2D sat, ivec2 size, int nk, float phi, float theta, out vec3 m[4]) {
    float fx = clamp(phi / (2.0 * PI) * float(size.x), 0.0, float(size.x));
    float fy = clamp(theta / PI * float(size.y), 0.0, float(size.y));
    int x0 = min(int(floor(fx)), size.x - 1);
    int y0 = min(int(floor(fy)), size.y - 1);
    float tx = fx - float(x0), ty = fy - float(y0);
    m[3] = vec3(0.0);
    for (int k = 0; k < nk; k++) {
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
    vec3 l0[4], l1[4], l2[4], l3[4];
    vv_lookup(sat, size, acc.nk, pb, tmin, l0);
    vv_lookup(sat, size, acc.nk, pa, tmin, l1);
    vv_lookup(sat, size, acc.nk, pb, tmax, l2);
    vv_lookup(sat, size, acc.nk, pa, tmax, l3);
    vec3 smin[4], bx[4];
    for (int k = 0; k < acc.nk; k++) {
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
    for (int k = 0; k < acc.nk; k++) acc.m[k] += smin[k] + f * bx[k];
}

// A sub-arc with small longitude span: seam split, then the piece.
void vv_seg(sampler2D sat, ivec2 size, float alpha, vec3 a, vec3 b, inout VvAcc acc) {
    vec2 A = vv_angles(a), B = vv_angles(b);
    if (sin(A.y) < 1e-6) A.x = B.x;
    if (sin(B.y) < 1e-6) B.x = A.x;
    float d = vv_wrap_pi(B.x - A.x);
    acc.dphi += d;
    float e = A.x + d;
    // up to two pieces (split at the seam); one call site keeps the inlined shaders small
    bool seam = e > 2.0 * PI || e < 0.0;
    vec3 p = b;
    float tp = B.y, sa = e, sb = 0.0;
    if (seam) {
        float t = a.x / (a.x - b.x);
        p = normalize(a + (b - a) * t);
        tp = vv_angles(p).y;
        sa = d > 0.0 ? 2.0 * PI : 0.0;
        sb = d > 0.0 ? 0.0 : 2.0 * PI;
    }
    for (int i = 0; i < (seam ? 2 : 1); i++) {
        bool f = i == 0;
        vv_piece(sat, size, alpha, f ? A.x : sb, f ? A.y : tp, f ? sa : sb + (e - sa), f ? tp : B.y, f ? a : p, f ? p : b, acc);
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
    bool split = false;
    vec3 sp = b;
    if (length(top) > 1e-7) {
        top = normalize(top);
        for (int s = 0; s < 2; s++) {
            vec3 p = s == 0 ? top : -top;
            if (!split && dot(cross(a, p), mh) > 1e-7 && dot(cross(p, b), mh) > 1e-7) {
                split = true;
                sp = p;
            }
        }
    }
    // one call site (a -> sp, then sp -> b when split)
    for (int i = 0; i < (split ? 2 : 1); i++) {
        vv_sub(sat, size, alpha, i == 0 ? a : sp, i == 0 ? sp : b, acc);
    }
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

// The whole-sphere correction of a loop sum whose loops all lie in a region excluding the south
// pole (`south_outside`) or else the north pole (penumbra_math::vv_sat::integrate_loops).
void vv_pole_fix(sampler2D sat, ivec2 size, bool south_outside, inout VvAcc acc) {
    if (!south_outside) {
        float w = round(acc.dphi / (2.0 * PI));
        for (int k = 0; k < acc.nk; k++) acc.m[k] -= w * vv_corner(sat, size, k, size.x, size.y);
    }
}

// ---- Specular cap ratio (eq. 14-16): loops clipped to a cap, streamed ----------------------
// GLSL port of penumbra_math::vv_sat::clip_to_cap for loops given point by point: the arcs of
// the clipped loop are integrated as they are produced (inside parts of the arcs, the cap's
// circle walked from each exit to the next entry, arcs dipping into the cap between two outside
// points), and a loop with no point in the cap adds the whole cap when it winds around the
// cap's axis (a cap enclosed by an occluder).

// Phong lobe cos^alpha -> cosine of the cap W holding 95% of its energy, at most 90 degrees
// (penumbra_math::vv_sat::phong_cap_cos).
float vv_phong_cap_cos(float alpha) {
    return clamp(pow(0.05, 1.0 / (max(alpha, 0.0) + 1.0)), 0.0, 1.0);
}

struct VvClip {
    vec3 axis;      // cap axis (nudged)
    float cosr;     // cap cosine
    vec3 u, v;      // vv_basis(axis)
    float sgn;      // +1: loop counter-clockwise seen from the centre (adds), -1: clockwise
    int steps;      // arcs of a full circle walk
    bool started, prev_in, any_in, crossed, has_exit, has_entry0;
    vec3 first, prev, exit_p, entry0;
    float wind;     // sum of the turning angles about the axis (winding number * -2 pi)
};

void vv_clip_init(vec3 axis, float cosr, float sgn, int steps, out VvClip c) {
    c.axis = axis;
    c.cosr = cosr;
    vv_basis(axis, c.u, c.v);
    c.sgn = sgn;
    c.steps = max(steps, 8);
    c.started = false;
    c.prev_in = false;
    c.any_in = false;
    c.crossed = false;
    c.has_exit = false;
    c.has_entry0 = false;
    c.first = vec3(0.0);
    c.prev = vec3(0.0);
    c.exit_p = vec3(0.0);
    c.entry0 = vec3(0.0);
    c.wind = 0.0;
}

vec3 vv_circle_point(VvClip c, float ang) {
    float sinr = sqrt(max(1.0 - c.cosr * c.cosr, 0.0));
    return normalize(c.axis * c.cosr + (c.u * cos(ang) + c.v * sin(ang)) * sinr);
}

float vv_circle_angle(VvClip c, vec3 p) {
    vec3 q = p - c.axis * dot(p, c.axis);
    return atan(dot(q, c.v), dot(q, c.u));
}

// Crossing of the great arc a -> b with the circle (bisection on the chord, as the CPU).
vec3 vv_clip_cross(VvClip c, vec3 a, vec3 b) {
    float lo = 0.0, hi = 1.0;
    bool glo = dot(a, c.axis) - c.cosr >= 0.0;
    for (int i = 0; i < 30; i++) {
        float mid = 0.5 * (lo + hi);
        bool gm = dot(normalize(a + (b - a) * mid), c.axis) - c.cosr >= 0.0;
        if (gm == glo) lo = mid; else hi = mid;
    }
    return normalize(a + (b - a) * (0.5 * (lo + hi)));
}

// Walk along the circle from `from` to `to`, keeping the cap on the left seen from the centre
// (sgn > 0, decreasing angle about the axis) or on the right (sgn < 0), arcs at most
// 2 pi / steps (penumbra_math::vv_sat::circle_walk): nw arcs, the i-th ending at angle
// a0 + i dang (the last one at `to`).
void vv_walk_params(VvClip c, vec3 from, vec3 to, out int nw, out float a0, out float dang) {
    a0 = vv_circle_angle(c, from);
    float a1 = vv_circle_angle(c, to);
    float span = mod(c.sgn > 0.0 ? a0 - a1 : a1 - a0, 2.0 * PI);
    int n = int(ceil(span / (2.0 * PI / float(c.steps))));
    nw = max(n, 1);
    dang = -c.sgn * span / float(nw);
}

// Integrates nw walk arcs from `from` (see vv_walk_params), then the great arc p -> q when
// has_arc. The shaders inline every function: a single vv_arc call site here (and in the
// callers) keeps the SPIR-V and lavapipe's pipeline compile small.
void vv_clip_emit(sampler2D sat, ivec2 size, float alpha, VvClip c, int nw, float a0, float dang, vec3 from, vec3 to, bool has_arc, vec3 p, vec3 q, inout VvAcc acc) {
    vec3 cur = from;
    for (int i = 1; i <= nw + (has_arc ? 1 : 0); i++) {
        vec3 x = p, y = q;
        if (i <= nw) {
            x = cur;
            y = i == nw ? to : vv_circle_point(c, a0 + dang * float(i));
            cur = y;
        }
        vv_arc(sat, size, alpha, x, y, acc);
    }
}

// One arc a -> b of the loop.
void vv_clip_arc(sampler2D sat, ivec2 size, float alpha, inout VvClip c, vec3 a, vec3 b, inout VvAcc acc) {
    bool ia = dot(a, c.axis) >= c.cosr, ib = dot(b, c.axis) >= c.cosr;
    c.wind += atan(dot(c.axis, cross(a, b)), dot(a, b) - dot(a, c.axis) * dot(b, c.axis));
    bool has_arc = false, entered = false;
    vec3 p = a, q = b, e = a;
    if (ia && ib) {
        has_arc = true;
    } else if (ia) {
        q = vv_clip_cross(c, a, b);
        has_arc = true;
        c.crossed = true;
        c.has_exit = true;
        c.exit_p = q;
    } else if (ib) {
        e = vv_clip_cross(c, a, b);
        entered = true;
        has_arc = true;
        p = e;
    } else {
        // both ends outside: the arc may dip into the cap (its point closest to the axis)
        vec3 m = cross(a, b);
        float ml = length(m);
        if (ml >= 1e-7) {
            vec3 mh = m / ml;
            vec3 t = c.axis - mh * dot(mh, c.axis);
            if (length(t) >= 1e-7) {
                t = normalize(t);
                if (dot(cross(a, t), mh) > 0.0 && dot(cross(t, b), mh) > 0.0 && dot(t, c.axis) > c.cosr) {
                    e = vv_clip_cross(c, a, t);
                    p = e;
                    q = vv_clip_cross(c, t, b);
                    entered = true;
                    has_arc = true;
                }
            }
        }
    }
    int nw = 0;
    float a0 = 0.0, dang = 0.0;
    vec3 wf = e;
    if (entered) {
        c.crossed = true;
        if (c.has_exit) {
            vv_walk_params(c, c.exit_p, e, nw, a0, dang);
            wf = c.exit_p;
            c.has_exit = false;
        } else if (!c.has_entry0) {
            c.has_entry0 = true;
            c.entry0 = e;
        }
        if (!ib) {
            // the dip's exit
            c.has_exit = true;
            c.exit_p = q;
        }
    }
    vv_clip_emit(sat, size, alpha, c, nw, a0, dang, wf, e, has_arc, p, q, acc);
}

// The loop's next point.
void vv_clip_push(sampler2D sat, ivec2 size, float alpha, inout VvClip c, vec3 p, inout VvAcc acc) {
    bool pin = dot(p, c.axis) >= c.cosr;
    c.any_in = c.any_in || pin;
    if (!c.started) {
        c.started = true;
        c.first = p;
    } else {
        vv_clip_arc(sat, size, alpha, c, c.prev, p, acc);
    }
    c.prev = p;
    c.prev_in = pin;
}

// Closes the loop (arc back to the first point, last walk), or adds the whole circle when no
// arc reached the cap and the loop winds around its axis. Resets the state for the next loop.
void vv_clip_end(sampler2D sat, ivec2 size, float alpha, inout VvClip c, inout VvAcc acc) {
    if (c.started) {
        vv_clip_arc(sat, size, alpha, c, c.prev, c.first, acc);
        int nw = 0;
        float a0 = 0.0, dang = 0.0;
        vec3 wf = c.exit_p, wt = c.entry0;
        if (c.has_exit && c.has_entry0) {
            vv_walk_params(c, c.exit_p, c.entry0, nw, a0, dang);
        } else if (!c.crossed && !c.any_in) {
            // winding about the axis, positive counter-clockwise seen from the centre
            float w = round(-c.wind / (2.0 * PI));
            if (w != 0.0) {
                // the full circle (penumbra_math::vv_sat::cap_loop), in the loop's direction
                nw = c.steps;
                a0 = 0.0;
                dang = (w > 0.0 ? -2.0 : 2.0) * PI / float(c.steps);
                wf = vv_circle_point(c, 0.0);
                wt = wf;
            }
        }
        if (nw > 0) vv_clip_emit(sat, size, alpha, c, nw, a0, dang, wf, wt, false, wf, wf, acc);
    }
    vv_clip_init(c.axis, c.cosr, c.sgn, c.steps, c);
}

// The cap W (axis r, cosine cos_xi; both as given to vv_clip_init for the occluders) as a
// positive loop of `steps` arcs (penumbra_math::vv_sat::cap_loop), clipped to the hemisphere of
// the (nudged) normal n.
void vv_add_cap_in_hemisphere(sampler2D sat, ivec2 size, float alpha, vec3 r, float cos_xi, vec3 n, int steps, inout VvAcc acc) {
    VvClip cap;
    vv_clip_init(r, cos_xi, 1.0, steps, cap);
    VvClip h;
    vv_clip_init(n, 0.0, 1.0, steps, h);
    for (int i = 0; i < cap.steps; i++) {
        vv_clip_push(sat, size, alpha, h, vv_circle_point(cap, -2.0 * PI * float(i) / float(cap.steps)), acc);
    }
    vv_clip_end(sat, size, alpha, h, acc);
}

// The plain cap W as a positive loop.
void vv_add_cap(sampler2D sat, ivec2 size, float alpha, vec3 r, float cos_xi, int steps, inout VvAcc acc) {
    VvClip cap;
    vv_clip_init(r, cos_xi, 1.0, steps, cap);
    vec3 p0 = vv_circle_point(cap, 0.0);
    vv_clip_emit(sat, size, alpha, cap, cap.steps, 0.0, -2.0 * PI / float(cap.steps), p0, p0, false, p0, p0, acc);
}

// Pole rule of a region inside the cap (r, cos_xi) and, when `hemi`, the hemisphere of n, then
// the cap-weighted integral of eq. 15-16: sum over the region of (l . r - cos_xi) L_e (rgb).
vec3 vv_cap_finish(sampler2D sat, ivec2 size, vec3 r, float cos_xi, bool hemi, vec3 n, inout VvAcc acc) {
    bool south_out = -r.y < cos_xi || (hemi && -n.y < 0.0);
    bool north_out = r.y < cos_xi || (hemi && n.y < 0.0);
    vv_pole_fix(sat, size, south_out || !north_out, acc);
    return acc.m[0] * r.x + acc.m[1] * r.y + acc.m[2] * r.z - acc.m[3] * cos_xi;
}

#endif
