//! The hemispherical map layout and the GPU HSDT on the Vulkan device (lavapipe): the GLSL layout
//! functions agree with `penumbra_math::avs_maps`, the GPU transform equals the CPU one up to fp16
//! rounding on random and adversarial maps (poles, seam, single-texel holes, slivers, all
//! visible/occluded) at r = 8, 24, 32, 64 and 256 (fp16 precision), across batches, validation clean
//! (with synchronization validation).

use glam::DVec3;
use penumbra::passes::hsdt::{decode_ssdf, Hsdt};
use penumbra::passes::trace::add_copy_to_readback;
use penumbra::passes::util::{bytes_of, compute_pipeline, dispatch, groups};
use penumbra_engine::{Access, Bind, Context, ContextDesc, Engine, Graph, PassKind};
use penumbra_math::avs_maps::{
    angle_between, dir_to_texel, f16_to_f32, f32_to_f16, texel_angle, texel_dir, texel_solid_angle, Frame, VisMap,
};
use penumbra_math::hsdt::{hsdt_f64, test_maps};

fn ctx() -> std::sync::Arc<Context> {
    Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context")
}

/// Runs the GPU HSDT of `maps` (batches of `batch` maps) and returns the decoded SSDFs.
fn gpu_hsdt(ctx: &std::sync::Arc<Context>, maps: &[VisMap], r: u32, batch: Option<u32>) -> Vec<Vec<f32>> {
    let lib = penumbra::shader_library();
    let mut h = Hsdt::new(ctx, &lib).expect("pipelines");
    h.batch = batch;
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let words: Vec<u32> = maps.iter().flat_map(|m| m.bits.iter().copied()).collect();
    let o = h.transform_alone(&mut engine, &words, maps.len() as u32, r).expect("hsdt passes");
    decode_ssdf(&o.readbacks["ssdf"], maps.len(), r)
}

/// |gpu - cpu| allowed: the fp16 rounding of the value (half an fp16 ulp) plus f32 evaluation.
fn f16_tolerance(v: f64) -> f64 {
    let h = f32_to_f16(v as f32);
    let ulp = (f16_to_f32(h + 1) - f16_to_f32(h)).abs() as f64;
    0.5 * ulp + 2e-5 * v.abs().max(1e-3)
}

fn check_maps(ctx: &std::sync::Arc<Context>, r: u32, maps: &[(String, VisMap)], batch: Option<u32>) -> (f64, f64) {
    let vis: Vec<VisMap> = maps.iter().map(|(_, m)| m.clone()).collect();
    let gpu = gpu_hsdt(ctx, &vis, r, batch);
    let mut worst: f64 = 0.0;
    let mut sum = 0.0;
    let mut cnt = 0usize;
    for ((name, m), gm) in maps.iter().zip(&gpu) {
        let cpu = hsdt_f64(m);
        for (k, (&c, &gv)) in cpu.iter().zip(gm).enumerate() {
            let e = (gv as f64 - c).abs();
            assert!(
                e <= f16_tolerance(c),
                "r={r} {name}: texel {k} ({}, {}) GPU {gv} vs CPU {c} (error {e:e})",
                k as u32 / r,
                k as u32 % r
            );
            assert_eq!(gv > 0.0, m.get(k as u32 / r, k as u32 % r), "r={r} {name}: sign of texel {k}");
            worst = worst.max(e);
            sum += e;
            cnt += 1;
        }
    }
    (worst, sum / cnt as f64)
}

#[test]
fn gpu_hsdt_matches_cpu_small_maps_and_batches() {
    let ctx = ctx();
    // batched runs first (fresh output memory): batches of 3 and 4 maps reuse the intermediate
    // buffer and append to the output, then everything in one batch
    let r = 32;
    let maps = test_maps(r, 5);
    check_maps(&ctx, r, &maps, Some(3));
    let m64: Vec<_> =
        test_maps(64, 7).into_iter().filter(|(n, _)| n.starts_with("random") || n.contains("pole")).collect();
    check_maps(&ctx, 64, &m64, Some(4));
    let (mx, mean) = check_maps(&ctx, r, &maps, None);
    println!("r={r}: {} maps, max |GPU - CPU| {mx:.3e} rad, mean {mean:.3e}", maps.len());
    // r = 8 (smallest) and r = 24 (rows straddle the 32-bit words the pass reads a row's bits by)
    check_maps(&ctx, 8, &test_maps(8, 6), None);
    check_maps(&ctx, 24, &test_maps(24, 8), None);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// fp16 SSDFs at r = 256: error against the exact f64 transform stays below 1/8 texel and the
/// smallest distances (one texel in phi next to the poles, ~h^2/2 = 7.5e-5 rad) keep their sign.
#[test]
fn fp16_precision_at_256() {
    let ctx = ctx();
    let r = 256;
    let maps: Vec<_> = test_maps(r, 11)
        .into_iter()
        .filter(|(n, _)| {
            n.contains("pole") || n.contains("seam: visible only") || n == "checkerboard" || n == "random caps 3"
        })
        .collect();
    assert_eq!(maps.len(), 5);
    let (mx, mean) = check_maps(&ctx, r, &maps, None);
    let h = texel_angle(r);
    println!("r=256: max |fp16 GPU - exact| {mx:.3e} rad = {:.4} texel, mean {mean:.3e} rad", mx / h);
    assert!(mx < h / 8.0, "fp16 error {mx} rad >= 1/8 texel ({h})");
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// The GLSL mirror (`glsl/include/avs_maps.glsl`, run by `glsl/tests/hsdt_layout_test.comp`) agrees with
/// the Rust layout: texel directions, solid angles, direction -> texel (poles, horizon, seam),
/// angular distances and both frame builders.
#[test]
fn glsl_layout_matches_cpu() {
    let ctx = ctx();
    let lib = penumbra::shader_library();
    let r = 16u32;
    let n = (r * r) as usize;
    // query directions: texel-interior random points, the poles, the horizon halves, the normal,
    // one below the horizon
    let mut dirs: Vec<DVec3> = Vec::with_capacity(n);
    let mut s = 0x1234_5678u64;
    let mut rnd = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for k in 0..n {
        let d = match k {
            0 => DVec3::new(1.0, 0.0, 1e-3),
            1 => DVec3::new(-1.0, 0.0, 1e-3),
            2 => DVec3::new(0.0, 1.0, 1e-7),
            3 => DVec3::new(0.0, -1.0, 1e-7),
            4 => DVec3::Z,
            5 => DVec3::new(0.3, 0.2, -0.5),
            _ => DVec3::new(2.0 * rnd() - 1.0, 2.0 * rnd() - 1.0, rnd()),
        };
        dirs.push(d.normalize());
    }
    let input: Vec<[f32; 4]> = dirs.iter().map(|d| [d.x as f32, d.y as f32, d.z as f32, 0.0]).collect();
    let pipe = compute_pipeline(&ctx, &lib, "tests/hsdt_layout_test.comp", 4).unwrap();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let mut g = Graph::new();
    let inb = g.create_buffer_init("dirs", bytes_of(&input));
    let outb = g.create_buffer("layout_out", (n * 4 * 16) as u64);
    let mut p = g.pass("layout_test", PassKind::Compute);
    let i = p.read(inb, Access::ComputeShaderReadStorage);
    let o = p.write(outb, Access::ComputeShaderWriteStorage);
    let h = pipe.handle();
    p.record(move |rc| {
        dispatch(rc, h, &[Bind::StorageBuffer(i), Bind::StorageBuffer(o)], &bytes_of(&[r]), [groups(r * r, 64), 1, 1])
    });
    add_copy_to_readback(&mut g, o, "layout_rb", (n * 4 * 16) as u64);
    engine.submit(g).unwrap();
    let out = engine.drain().unwrap().pop().unwrap();
    let f: Vec<f32> =
        out.readbacks["layout_rb"].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    let v = |k: usize, q: usize| {
        DVec3::new(f[16 * k + 4 * q] as f64, f[16 * k + 4 * q + 1] as f64, f[16 * k + 4 * q + 2] as f64)
    };
    let mut edge_skips = 0;
    for k in 0..n {
        let (ti, tj) = (k as u32 / r, k as u32 % r);
        assert!((v(k, 0) - texel_dir(ti, tj, r)).length() < 1e-5, "texel_dir {k}");
        assert!((f[16 * k + 3] as f64 - texel_solid_angle(ti, r)).abs() < 1e-6, "solid angle {k}");
        let k2 = (k * 7919) % n;
        let d = angle_between(texel_dir(ti, tj, r), texel_dir(k2 as u32 / r, k2 as u32 % r, r));
        assert!((f[16 * k + 7] as f64 - d).abs() < 1e-5, "distance {k}: {} vs {d}", f[16 * k + 7]);
        let cpu = dir_to_texel(dirs[k], r);
        let found = f[16 * k + 6] == 1.0;
        assert_eq!(found, cpu.is_some(), "dir_to_texel found {k}");
        if let Some((ci, cj)) = cpu {
            let (gi, gj) = (f[16 * k + 4] as u32, f[16 * k + 5] as u32);
            // f32 vs f64 may disagree only for directions within ~1e-6 of a texel edge
            let th = dirs[k].x.acos() * r as f64 / std::f64::consts::PI;
            let ph = dirs[k].z.max(0.0).atan2(dirs[k].y) * r as f64 / std::f64::consts::PI;
            let near_edge = (th - th.round()).abs() < 1e-4 || (ph - ph.round()).abs() < 1e-4;
            if (gi, gj) != (ci, cj) {
                assert!(near_edge, "dir_to_texel {k}: GPU ({gi},{gj}) CPU ({ci},{cj})");
                edge_skips += 1;
            }
            if k < 5 {
                // poles: row only (phi undefined); horizon halves and normal: exact
                assert_eq!(gi, ci, "dir_to_texel {k} row");
                if k >= 2 {
                    assert_eq!(gj, cj, "dir_to_texel {k} column");
                }
            }
        }
        let fr = Frame::from_normal(dirs[k]);
        assert!((v(k, 2) - fr.t).length() < 1e-5, "avs_frame {k}");
        let fh = Frame::from_normal_hint(dirs[k], DVec3::Y);
        assert!((v(k, 3) - fh.t).length() < 1e-4, "avs_frame_hint {k}: {:?} vs {:?}", v(k, 3), fh.t);
    }
    assert!(edge_skips <= 2, "{edge_skips} edge disagreements");
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// The GLSL SSDF integrals (`glsl/include/ssdf_integrate.glsl`, run by
/// `glsl/tests/hsdt_integrate_test.comp` on GPU-made fp16 SSDFs) agree with the CPU versions
/// (`penumbra_math::ssdf_integrate`) evaluated on the same fp16 values: random cap occluders,
/// all visible / all occluded, lambda 1e-2..1e4, grazing and below-horizon axes, with and
/// without the cosine.
#[test]
fn glsl_integrals_match_cpu() {
    use penumbra_math::sg::Sg;
    use penumbra_math::ssdf_integrate::{visible_axis, visible_cells, AxisTable, SsdfView};
    let ctx = ctx();
    let lib = penumbra::shader_library();
    let r = 32u32;
    let mut maps: Vec<VisMap> = test_maps(r, 21)
        .into_iter()
        .filter(|(n, _)| n.starts_with("random caps") || n.starts_with("all") || n.contains("hole"))
        .map(|(_, m)| m)
        .collect();
    maps.truncate(6);
    let ssdf = gpu_hsdt(&ctx, &maps, r, None);
    let table = AxisTable::generate(|_| {});
    let axes = [
        DVec3::Z,
        DVec3::new(0.4, -0.3, 0.8),
        DVec3::new(-0.7, 0.2, 0.3),
        DVec3::new(0.1, 0.99, 0.02),
        DVec3::new(0.3, -0.5, -0.2),
    ];
    let mut lobes: Vec<[f32; 4]> = Vec::new();
    let mut params: Vec<[f32; 4]> = Vec::new();
    let mut cpu: Vec<(f64, f64, f64)> = Vec::new();
    for (mi, vals) in ssdf.iter().enumerate() {
        let view = SsdfView { r, values: vals };
        for (k, a) in axes.iter().enumerate() {
            let a = a.normalize();
            let lambda = [1e-2, 2.0, 60.0, 900.0, 1e4][(k + mi) % 5];
            let cosine = (k + mi) % 2 == 0;
            let g = Sg::new(a, lambda, 1.0);
            lobes.push([a.x as f32, a.y as f32, a.z as f32, lambda as f32]);
            params.push([1.0, cosine as u32 as f32, mi as f32, 0.0]);
            cpu.push((visible_axis(&view, &table, &g, cosine), visible_cells(&view, &g, cosine), g.sphere_integral()));
        }
    }
    let n = lobes.len();
    let words: Vec<u32> = ssdf.iter().flat_map(|v| penumbra_math::avs_maps::pack_ssdf_f16(v)).collect();
    let pipe = compute_pipeline(&ctx, &lib, "tests/hsdt_integrate_test.comp", 8).unwrap();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let mut g = Graph::new();
    let bufs = [
        g.create_buffer_init("int_ssdf", bytes_of(&words)),
        g.create_buffer_init("int_table", bytes_of(&table.data)),
        g.create_buffer_init("int_lobes", bytes_of(&lobes)),
        g.create_buffer_init("int_params", bytes_of(&params)),
    ];
    let outb = g.create_buffer("int_out", (n * 8) as u64);
    let mut p = g.pass("integrate_test", PassKind::Compute);
    let ins: Vec<_> = bufs.iter().map(|b| p.read(*b, Access::ComputeShaderReadStorage)).collect();
    let o = p.write(outb, Access::ComputeShaderWriteStorage);
    let h = pipe.handle();
    p.record(move |rc| {
        let mut binds: Vec<Bind> = ins.iter().map(|b| Bind::StorageBuffer(*b)).collect();
        binds.push(Bind::StorageBuffer(o));
        dispatch(rc, h, &binds, &bytes_of(&[r, n as u32]), [groups(n as u32, 16), 1, 1])
    });
    add_copy_to_readback(&mut g, o, "int_rb", (n * 8) as u64);
    engine.submit(g).unwrap();
    let out = engine.drain().unwrap().pop().unwrap();
    let f: Vec<f32> =
        out.readbacks["int_rb"].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    let mut worst: f64 = 0.0;
    for (q, (ca, cc, full)) in cpu.iter().enumerate() {
        let (ga, gc) = (f[2 * q] as f64, f[2 * q + 1] as f64);
        let ea = (ga - ca).abs() / full;
        let ec = (gc - cc).abs() / full;
        assert!(
            ea < 2e-3 && ec < 2e-3,
            "lobe {q} ({:?}, {:?}): GPU ({ga}, {gc}) CPU ({ca}, {cc})",
            lobes[q],
            params[q]
        );
        worst = worst.max(ea).max(ec);
    }
    println!("{n} (map, lobe) pairs: max |GPU - CPU| = {worst:.2e} of the lobe's sphere integral");
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}
