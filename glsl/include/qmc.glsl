// Randomized quasi-Monte Carlo sample points: Owen-scrambled Sobol' points, shuffled per
// dimension pair (Burley 2020, "Practical Hash-based Owen Scrambling", JCGT 9(4)).
//
// qmc_2d(i, seed) is point i of a 2D Sobol' (0,2)-sequence (its first two dimensions), with
// the index and both coordinates nested-uniform (Owen) scrambled by hashes of `seed`. Any
// aligned block of 2^k consecutive indices (in particular 0 .. 2^k - 1) is a (0,k,2)-net: every
// elementary interval of area 2^-k (2^a x 2^(k-a) cells) holds exactly one point, whatever the
// seed. Independent seeds per dimension pair pad the 2D points into as many dimensions as an
// estimator needs (Kollig and Keller 2002), and independent seeds per pixel decorrelate pixels.
// No loops: nothing here counts against a driver's loop limit.
#ifndef PENUMBRA_QMC_GLSL
#define PENUMBRA_QMC_GLSL

// A hash of 32 bits (the PCG output permutation of one LCG step).
uint qmc_hash(uint v) {
    uint s = v * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

// Laine and Karras's permutation with Burley's constants: bit k of the result is bit k of x
// flipped by a function of the bits below k (additions and products by even constants carry
// upwards only), so on bit-reversed input it is an Owen scramble.
uint qmc_lk_permute(uint x, uint seed) {
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

// Nested uniform scramble of x read as a binary fraction, most significant bit first.
uint qmc_owen(uint x, uint seed) { return bitfieldReverse(qmc_lk_permute(bitfieldReverse(x), seed)); }

// Sobol's second dimension (primitive polynomial x + 1: v_1 = 1/2, v_k = v_(k-1) xor v_(k-1)/2),
// its 32 bits as a fraction. Its generator matrix is Pascal's triangle mod 2: bit j of the
// fraction (weight 2^-(j+1)) is the parity of the index bits i_k with j a bit subset of k (Lucas),
// a superset-sum over the five bits of the position, i.e. five shift-xor steps.
uint qmc_sobol1(uint i) {
    i ^= (i >> 1u) & 0x55555555u;
    i ^= (i >> 2u) & 0x33333333u;
    i ^= (i >> 4u) & 0x0f0f0f0fu;
    i ^= (i >> 8u) & 0x00ff00ffu;
    i ^= i >> 16u;
    return bitfieldReverse(i);
}

// Point i in [0, 1)^2 of the sequence `seed` names.
vec2 qmc_2d(uint i, uint seed) {
    uint s0 = qmc_hash(seed), s1 = qmc_hash(s0 ^ 0x5bd1e995u), s2 = qmc_hash(s1 ^ 0x27d4eb2fu);
    uint j = qmc_owen(i, s0);
    // Sobol's first dimension is the bit reversal of the index (van der Corput): scrambling it
    // is the permutation without the reversals
    uint x = bitfieldReverse(qmc_lk_permute(j, s1));
    uint y = qmc_owen(qmc_sobol1(j), s2);
    // 24 bits: the float of the fraction stays below 1
    return vec2(float(x >> 8u), float(y >> 8u)) * (1.0 / 16777216.0);
}

// The seed of dimension pair `dim` of the pixel sequence `pixel_seed`.
uint qmc_dim_seed(uint pixel_seed, uint dim) { return qmc_hash(pixel_seed ^ qmc_hash(dim + 0x9e3779b9u)); }

#endif
