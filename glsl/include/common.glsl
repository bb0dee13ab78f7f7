// Shared declarations: camera block, encodings, lat-long mapping (same convention as
// penumbra_scene::Environment::direction: v = 0 is +Y, phi = 2*pi*u grows from -Z towards +X).
#ifndef PENUMBRA_COMMON_GLSL
#define PENUMBRA_COMMON_GLSL

#define PI 3.14159265358979323846

struct CameraData {
    mat4 view_proj;
    mat4 prev_view_proj;
    mat4 inv_view_proj;
    vec4 eye;          // xyz eye position
    vec4 params;       // x width, y height, z env mip count, w env intensity
    vec4 env_rot;      // x cos(rotation), y sin(rotation), z exposure, w unused
                       // (rotation and intensity: the frame's, penumbra_scene::Frame::environment)
};

struct InstanceData {
    mat4 model;
    mat4 prev_model;
    mat4 normal_matrix;
    uvec4 ids;         // x material, y instance id
};

struct MaterialData {
    vec4 albedo_kind;  // rgb albedo, w kind (0 diffuse, 1 Blinn-Phong, 2 Cook-Torrance, 3 Ashikhmin-Shirley)
    vec4 spec_rough;   // rgb specular F0, w roughness
    vec4 extra;        // x shininess (Blinn-Phong, Ashikhmin-Shirley nu), y albedo map layer (-1 none),
                       // z roughness map layer (-1 none), w Ashikhmin-Shirley nv (= x if isotropic)
                       // (read through material.glsl's material_at)
    vec4 emission;     // rgb emitted radiance (seen by the eye only), w emission map layer (-1 none)
    vec4 normal;       // x tangent-space normal map layer (-1 none), y its scale (material_normal)
};

struct LightData {
    vec4 pos_kind;         // xyz position, w kind (0 point, 1 spot, 2 sphere, 3 directional)
    vec4 dir_cos_outer;    // xyz unit direction (spot, directional), w cos(outer half-angle)
    vec4 power_cos_inner;  // rgb colour * intensity, w cos(inner half-angle)
    vec4 extra;            // x sphere radius, yzw the medium's extinction sigma_t (0 without a medium)
};

// Local light reaching a point at distance d from the light through the scene's homogeneous
// medium: exp(-sigma_t d) (1 without a medium), as the reference attenuates it on its way in.
vec3 medium_transmittance(vec3 sigma_t, float d) {
    return exp(-sigma_t * d);
}
vec3 light_transmittance(LightData l, float d) {
    return medium_transmittance(l.extra.yzw, d);
}

vec2 oct_wrap(vec2 v) {
    return (1.0 - abs(v.yx)) * vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

vec2 oct_encode(vec3 n) {
    n /= (abs(n.x) + abs(n.y) + abs(n.z));
    vec2 e = n.z >= 0.0 ? n.xy : oct_wrap(n.xy);
    return e;
}

vec3 oct_decode(vec2 e) {
    vec3 n = vec3(e.x, e.y, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) n.xy = oct_wrap(n.xy);
    return normalize(n);
}

// The G-buffer's geometric normal, in gb_position.w: octahedral with 11 bits per coordinate,
// stored as the integer 1 + qx + 2048 qy (exact in fp32; > 0 marks a covered pixel, the sky
// stays 0). The face's normal, turned to the side of the interpolated vertex normal (the
// reference's ng): light from below it is blocked by the surface itself.
float gb_pack_geometric_normal(vec3 ng) {
    uvec2 q = uvec2(round(clamp(oct_encode(ng) * 0.5 + 0.5, 0.0, 1.0) * 2047.0));
    return float(1u + q.x + 2048u * q.y);
}
vec3 gb_geometric_normal(float w) {
    uint u = uint(max(w, 1.0)) - 1u;
    return oct_decode(vec2(float(u & 2047u), float(u >> 11u)) / 2047.0 * 2.0 - 1.0);
}

// Lat-long (u, v) for a world direction, after undoing the environment rotation about +Y.
vec2 dir_to_latlong(vec3 d, vec2 cos_sin_rot) {
    // Rotate by -rotation about +Y.
    float c = cos_sin_rot.x, s = cos_sin_rot.y;
    vec3 r = vec3(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
    float theta = acos(clamp(r.y, -1.0, 1.0));
    float phi = atan(r.x, -r.z);
    if (phi < 0.0) phi += 2.0 * PI;
    return vec2(phi / (2.0 * PI), theta / PI);
}

// Bilinear taps of a w x h lat-long grid stored in a buffer, at continuous texel coordinates
// (fx, fy): columns wrap, rows clamp. Returns the columns and rows (x0, x1, y0, y1); `f` gets the
// weights of x1 and y1. Shared by the prefiltered-environment and irradiance buffers.
ivec4 latlong_taps(float fx, float fy, int w, int h, out vec2 f) {
    fy = clamp(fy, 0.0, float(h - 1));
    int x0 = int(floor(fx));
    int y0 = int(floor(fy));
    f = vec2(fx - float(x0), fy - float(y0));
    int y1 = min(y0 + 1, h - 1);
    x0 -= w * int(floor(float(x0) / float(w)));  // wrap (GLSL % is undefined for negatives)
    x0 = clamp(x0, 0, w - 1);
    int x1 = x0 + 1 == w ? 0 : x0 + 1;
    return ivec4(x0, x1, y0, y1);
}

#endif
