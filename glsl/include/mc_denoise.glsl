// Shared by mc-denoised's passes (glsl/mc/mcd_temporal.comp, glsl/mc/mcd_atrous.comp): the
// reflectance that demodulates mc's radiance into illumination before it is accumulated and
// filtered, and multiplies it back afterwards (SVGF, Schied et al. 2017, section 4: texture
// detail is not blurred), from the one material model. The includer declares `mats[]` and
// `material_textures` and includes material.glsl first.
#ifndef PENUMBRA_MC_DENOISE_GLSL
#define PENUMBRA_MC_DENOISE_GLSL

float mcd_luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

// What the a-trous filter's luminance edge-stopping compares: the (demodulated) radiance's
// luminance, or with the ratio estimator the visible fraction, shadowed over unshadowed
// luminance in [0, 1] (1 where nothing lit it: nothing to tell apart), so that a hard shadow's
// edge stops the filter and a highlight's noise does not.
float mcd_edge_value(vec3 shadowed, vec3 unshadowed, bool ratio) {
    if (!ratio) return mcd_luminance(shadowed);
    float u = mcd_luminance(unshadowed);
    return u > 0.0 ? clamp(mcd_luminance(shadowed) / u, 0.0, 1.0) : 1.0;
}

// Diffuse albedo plus specular colour of a textured material (of the pixel's, from its `uvm`),
// floored so that black surfaces keep their (emitted) radiance.
vec3 mcd_reflectance_of(MaterialData m) {
    return max(m.albedo_kind.rgb + m.spec_rough.rgb, vec3(1e-3));
}

// The material under the pixel (`uvm`: the G-buffer's uv, material index).
MaterialData mcd_material(vec4 uvm) {
    return material_at(mats[int(uvm.z + 0.5)], uvm.xy, material_textures);
}

vec3 mcd_reflectance(vec4 uvm) { return mcd_reflectance_of(mcd_material(uvm)); }

#endif
