// Real SH of order 4 (16 coefficients) at a unit direction, in the convention of
// penumbra_math::sh (index l*l + l + m, Condon-Shortley phase: Y_1^-1 = -0.4886 y, Y_1^1 = -0.4886 x).
// The one copy of the basis: avs's visibility maps and shadow fields' occlusion and lighting.
#ifndef PENUMBRA_SH16_GLSL
#define PENUMBRA_SH16_GLSL
void sh16_basis(vec3 d, out float y[16]) {
    float x = d.x, yy = d.y, z = d.z;
    y[0] = 0.28209479177;
    y[1] = -0.48860251190 * yy;
    y[2] = 0.48860251190 * z;
    y[3] = -0.48860251190 * x;
    y[4] = 1.09254843059 * x * yy;
    y[5] = -1.09254843059 * yy * z;
    y[6] = 0.31539156525 * (3.0 * z * z - 1.0);
    y[7] = -1.09254843059 * x * z;
    y[8] = 0.54627421529 * (x * x - yy * yy);
    y[9] = -0.59004358992 * yy * (3.0 * x * x - yy * yy);
    y[10] = 2.89061144264 * x * yy * z;
    y[11] = -0.45704579946 * yy * (5.0 * z * z - 1.0);
    y[12] = 0.37317633259 * z * (5.0 * z * z - 3.0);
    y[13] = -0.45704579946 * x * (5.0 * z * z - 1.0);
    y[14] = 1.44530572132 * z * (x * x - yy * yy);
    y[15] = -0.59004358992 * x * (x * x - 3.0 * yy * yy);
}
#endif
