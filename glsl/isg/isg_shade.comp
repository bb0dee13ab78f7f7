#version 450
// ISG shading per pixel (Iwasaki et al. 2012): see glsl/include/isg_shade.glsl.
#include "isg_shade.glsl"
