//! The GPU's specular albedo table (`penumbra_math::dfg`, read by `env_shade.glsl`) integrates
//! the reference's own BRDFs: checked against `Brdf::eval` by brute-force quadrature.

use glam::Vec3;
use penumbra_math::dfg::{blinn_phong_albedo, ggx_albedo};
use penumbra_reference::brdf::{blinn_phong_normal_albedo, Brdf};
use penumbra_scene::{BrdfKind, Material};

/// The albedo (red channel) of a BRDF at n.v = `ndv` by quadrature over the hemisphere
/// (stratified cosine-weighted directions), from `Brdf::eval` itself.
fn brute_albedo(b: &Brdf, ndv: f32) -> f64 {
    let wo = Vec3::new((1.0 - ndv * ndv).sqrt(), 0.0, ndv);
    let n = 600;
    let mut sum = 0.0;
    for a in 0..n {
        for c in 0..n {
            let u1 = (a as f32 + 0.5) / n as f32;
            let u2 = (c as f32 + 0.5) / n as f32;
            let r = u1.sqrt();
            let phi = std::f32::consts::TAU * u2;
            let wi = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).sqrt());
            // pdf = cos / pi: eval cos / pdf = eval pi
            sum += b.eval(wo, wi).x as f64 * std::f64::consts::PI;
        }
    }
    sum / (n * n) as f64
}

fn material(kind: BrdfKind, specular: f32, roughness: f32, shininess: f32) -> Material {
    let mut m = Material::diffuse("m", Vec3::ZERO);
    m.kind = kind;
    m.specular = Vec3::splat(specular);
    m.roughness = roughness;
    m.shininess = shininess;
    m
}

#[test]
fn cook_torrance_albedo_is_the_reference_brdfs() {
    for (r, ndv) in [(0.5f32, 0.5f32), (0.7, 0.2), (0.9, 0.9), (0.5, 0.1), (0.25, 0.6)] {
        let (a, b) = ggx_albedo((r * r) as f64, ndv as f64);
        for f0 in [1.0f32, 0.0, 0.9] {
            let brute = brute_albedo(&Brdf::from_material(&material(BrdfKind::CookTorrance, f0, r, 0.0)), ndv);
            let ours = f0 as f64 * a + b;
            assert!(
                (ours - brute).abs() < 0.01 + 0.01 * brute,
                "r {r} n.v {ndv} F0 {f0}: table {ours}, quadrature {brute}"
            );
        }
    }
}

#[test]
fn blinn_phong_albedo_is_the_reference_brdfs() {
    // normal incidence in closed form, at every exponent
    for s in [0.0, 1.0, 10.0, 100.0, 1000.0, 1e5] {
        let want = blinn_phong_normal_albedo(s);
        let got = blinn_phong_albedo(s, 1.0);
        assert!((got - want).abs() < 2e-3, "s {s}: {got} against {want}");
    }
    for (s, ndv) in [(10.0f32, 0.3f32), (80.0, 0.6), (2.0, 0.15)] {
        let brute = brute_albedo(&Brdf::from_material(&material(BrdfKind::BlinnPhong, 1.0, 0.5, s)), ndv);
        let got = blinn_phong_albedo(s as f64, ndv as f64);
        assert!((got - brute).abs() < 0.01 + 0.01 * brute, "s {s} n.v {ndv}: {got} against {brute}");
    }
}
