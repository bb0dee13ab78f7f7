// Cube face and continuous texel coordinates (x, y in [0, n)) of direction d (any length > 0),
// faces and orientation as penumbra_math::shadow_field::haar::CubeTable: the wavelet shadow
// fields' maps (sfw_shade.comp) and per-vertex self-visibility maps (sfw_self.comp).
#ifndef SFW_CUBE_GLSL
#define SFW_CUBE_GLSL

void cube_coords(vec3 d, uint n, out uint face, out vec2 xy) {
    vec3 a = abs(d);
    float u, v, m;
    if (a.x >= a.y && a.x >= a.z) {
        m = a.x;
        face = d.x > 0.0 ? 0u : 1u;
        u = d.x > 0.0 ? -d.z : d.z;
        v = d.y;
    } else if (a.y >= a.z) {
        m = a.y;
        face = d.y > 0.0 ? 2u : 3u;
        u = d.x;
        v = d.y > 0.0 ? -d.z : d.z;
    } else {
        m = a.z;
        face = d.z > 0.0 ? 4u : 5u;
        u = d.z > 0.0 ? d.x : -d.x;
        v = d.y;
    }
    m = max(m, 1e-30);
    xy = (vec2(u, v) / m + 1.0) * 0.5 * float(n);
}

#endif
