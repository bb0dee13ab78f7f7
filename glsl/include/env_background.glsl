// The environment seen along d where a view ray hits nothing: the nearest texel of the lat-long
// map's level 0, as the reference reads it (`Environment::radiance`). A bilinear tap blends two
// texel rows along a sharp horizon, so a whole image row of a grid-sampled pixel came out
// between them (the bare bunny's top row: 0.71 against 1.09). Needs `cam` (CameraData) and
// `env_map` (sampler2D) declared by the includer, and common.glsl.
#ifndef PENUMBRA_ENV_BACKGROUND_GLSL
#define PENUMBRA_ENV_BACKGROUND_GLSL
vec3 env_background(vec3 d) {
    vec2 uv = dir_to_latlong(normalize(d), cam.env_rot.xy);
    ivec2 size = textureSize(env_map, 0);
    ivec2 t = clamp(ivec2(uv * vec2(size)), ivec2(0), size - 1);
    return texelFetch(env_map, t, 0).rgb * cam.params.w;
}
#endif
