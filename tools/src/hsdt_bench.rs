//! `penumbra bench hsdt`: the hemispherical distance transform and the SSDF integrals of issue 8
//! part A, in one run per resolution: t_S per point and per 1000 points (GPU timestamps) against
//! the CPU transform (all cores and one core), GPU fp16 against the exact transform, the HSDT
//! against the brute-force spherical distance transform (random and adversarial maps), the two
//! lighting integrals against brute-force integration over the binary map, and GPU time per lobe
//! of each integral.

use anyhow::{anyhow, Result};
use clap::Args;
use glam::DVec3;
use indicatif::{ProgressBar, ProgressStyle};
use penumbra::engine::{Context, Engine, Graph};
use penumbra_math::avs_maps::{pack_ssdf_f16, texel_angle, VisMap};
use penumbra_math::hsdt::{field_error, hsdt, hsdt_f64, random_cap_map, ssdf_brute_force, test_maps};
use penumbra_math::sg::Sg;
use penumbra_math::ssdf_integrate::{brute_force, visible_axis, visible_cells, AxisTable, SsdfView};
use penumbra_passes::hsdt::{decode_ssdf, Hsdt};
use penumbra_passes::kernels::hsdt::IntegrateEval;
use penumbra_passes::trace::add_copy_to_readback;
use penumbra_passes::util::{bytes_of, copy_buffer, fill_buffer};
use std::time::Instant;

#[derive(Args)]
pub struct HsdtArgs {
    /// Visibility-map resolutions r (comma list; each a multiple of 8 in [8, 256]).
    #[arg(long, default_value = "64,128,256")]
    pub r: String,
    /// Sample points (maps) transformed per resolution.
    #[arg(long, default_value_t = 1000)]
    pub points: u32,
    /// Random maps checked against the brute-force transform (O(r^4) each) and used for the
    /// integral errors, per resolution (the adversarial maps are checked too up to r = 128).
    #[arg(long, default_value_t = 2)]
    pub verify: usize,
    /// Seed of the random maps.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Only the speed table (t_S, bytes moved, the host's memory bandwidth): skips the
    /// brute-force checks and the integrals.
    #[arg(long)]
    pub speed_only: bool,
}

impl HsdtArgs {
    /// The resolutions, or a message naming the bad value.
    pub fn resolutions(&self) -> Result<Vec<u32>, String> {
        let mut out = Vec::new();
        for s in self.r.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let r: u32 = s.parse().map_err(|_| format!("--r: '{s}' is not a number"))?;
            penumbra_math::avs_maps::check_res(r).map_err(|e| format!("--r: {e}"))?;
            out.push(r);
        }
        if out.is_empty() {
            return Err("--r: no resolution given".into());
        }
        if self.points == 0 {
            return Err("--points must be at least 1".into());
        }
        if self.points > 65535 * 64 {
            return Err(format!("--points {}: at most {}", self.points, 65535 * 64));
        }
        Ok(out)
    }
}

/// `f` over `items` on all cores (scoped threads, contiguous chunks), results in order.
fn par_map<T: Sync, U: Send>(items: &[T], f: impl Fn(usize, &T) -> U + Sync) -> Vec<U> {
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).max(1);
    let chunk = items.len().div_ceil(threads).max(1);
    let f = &f;
    std::thread::scope(|s| {
        let handles: Vec<_> = items
            .chunks(chunk)
            .enumerate()
            .map(|(c, part)| {
                s.spawn(move || part.iter().enumerate().map(|(i, x)| f(c * chunk + i, x)).collect::<Vec<U>>())
            })
            .collect();
        handles.into_iter().flat_map(|h| h.join().expect("worker thread")).collect()
    })
}

/// `f` over `items` on all cores, items handed out one at a time (uneven costs).
fn par_map_each<T: Sync, U: Send>(items: &[T], f: impl Fn(&T) -> U + Sync) -> Vec<U> {
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).max(1);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let out: Vec<std::sync::Mutex<Option<U>>> = items.iter().map(|_| std::sync::Mutex::new(None)).collect();
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if i >= items.len() {
                    break;
                }
                let v = f(&items[i]);
                *out[i].lock().unwrap() = Some(v);
            });
        }
    });
    out.into_iter().map(|m| m.into_inner().unwrap().expect("computed")).collect()
}

fn bar(n: u64, msg: &str) -> ProgressBar {
    let pb = ProgressBar::new(n);
    pb.set_style(
        ProgressStyle::with_template("{msg:>28} [{bar:40}] {pos}/{len} {elapsed}").unwrap().progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// The host's memory bandwidth in bytes per second (read + write): every core copies its part of
/// a 256 MiB buffer (well past the caches) into another, best of five.
fn host_copy_bandwidth() -> f64 {
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).max(1);
    let words = (256usize << 20) / 8;
    let src: Vec<u64> = (0..words as u64).collect();
    let mut dst = vec![0u64; words];
    let chunk = words.div_ceil(threads);
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t0 = Instant::now();
        std::thread::scope(|s| {
            for (d, sr) in dst.chunks_mut(chunk).zip(src.chunks(chunk)) {
                s.spawn(move || d.copy_from_slice(sr));
            }
        });
        best = best.min(t0.elapsed().as_secs_f64());
        std::hint::black_box(&dst);
    }
    2.0 * (words * 8) as f64 / best
}

/// The device's memory bandwidth in bytes per second (read + write): a 256 MiB buffer copied into
/// another by the device (the copy pass's timestamps), best of three.
fn device_copy_bandwidth(engine: &mut Engine) -> Result<f64> {
    let bytes = 256u64 << 20;
    let mut best = f64::MAX;
    for _ in 0..3 {
        let mut g = Graph::new();
        let src = g.create_buffer("bw_src", bytes);
        let dst = g.create_buffer("bw_dst", bytes);
        let src = fill_buffer(&mut g, "bw_fill", src, 0x3f80_0000);
        let (_, dst) = copy_buffer(&mut g, "bw_copy", src, dst, None);
        add_copy_to_readback(&mut g, dst, "bw", 4);
        engine.submit(g)?;
        let o = engine.drain()?.pop().ok_or_else(|| anyhow!("no frame output"))?;
        best = best.min(gpu_ms(&o, &["bw_copy"]));
    }
    Ok(2.0 * bytes as f64 / (best * 1e-3).max(1e-9))
}

fn gpu_ms(out: &penumbra::engine::FrameOutput, prefix: &[&str]) -> f64 {
    out.gpu_ms.iter().filter(|(n, _)| prefix.iter().any(|p| n.starts_with(p))).map(|(_, ms)| ms).sum()
}

pub fn run(args: &HsdtArgs) -> Result<()> {
    let rs = args.resolutions().map_err(|e| anyhow!(e))?;
    let ctx = Context::new(&Default::default())?;
    println!("device: {} ({})", ctx.device_name, ctx.driver_info());
    let lib = penumbra::shader_library();
    let hsdt_gpu = Hsdt::new(&ctx, &lib)?;
    let integ = IntegrateEval::new(&ctx, &lib)?;
    // the integrals' table (not needed for the speed tables alone)
    let table = (!args.speed_only).then(|| {
        let pb = bar(penumbra_math::ssdf_integrate::N_LAMBDA as u64, "T(lambda, d) table");
        let t = AxisTable::generate(|_| pb.inc(1));
        pb.finish();
        t
    });
    let n = args.points;
    let mut speed_rows = Vec::new();
    let mut traffic_rows = Vec::new();
    let mut acc_rows = Vec::new();
    let mut int_rows = Vec::new();
    for &r in &rs {
        let h = texel_angle(r);
        let pb = bar(n as u64, &format!("r={r}: random maps"));
        let ids: Vec<u32> = (0..n).collect();
        let maps: Vec<VisMap> = par_map(&ids, |_, &p| {
            let m = random_cap_map(r, args.seed.wrapping_mul(1_000_003).wrapping_add(p as u64));
            pb.inc(1);
            m
        });
        pb.finish();
        // GPU: warm-up, then the measured run
        let words: Vec<u32> = maps.iter().flat_map(|m| m.bits.iter().copied()).collect();
        let mut engine = Engine::new(ctx.clone(), 1)?;
        engine.timestamps = true;
        let mut run_gpu = || -> Result<(Vec<Vec<f32>>, f64)> {
            let o = hsdt_gpu.transform_alone(&mut engine, &words, n, r)?;
            Ok((decode_ssdf(&o.readbacks["ssdf"], n as usize, r), gpu_ms(&o, &["hsdt_b"])))
        };
        run_gpu()?;
        let (gpu, t_s) = run_gpu()?;
        // CPU: all cores, and one core on a subset
        let t0 = Instant::now();
        let cpu: Vec<Vec<f64>> = par_map(&maps, |_, m| hsdt_f64(m));
        let cpu_all_ms = t0.elapsed().as_secs_f64() * 1e3;
        let sub = (n as usize).min(if r >= 256 { 20 } else { 100 });
        let t0 = Instant::now();
        for m in &maps[..sub] {
            std::hint::black_box(hsdt(m));
        }
        let cpu_one_ms = t0.elapsed().as_secs_f64() * 1e3 * n as f64 / sub as f64;
        // GPU fp16 against the exact transform
        let errs: Vec<(f64, f64)> =
            par_map(&gpu, |i, g| field_error(&g.iter().map(|&v| v as f64).collect::<Vec<_>>(), &cpu[i]));
        let fp16_max = errs.iter().map(|e| e.0).fold(0.0, f64::max);
        let fp16_mean = errs.iter().map(|e| e.1).sum::<f64>() / errs.len() as f64;
        speed_rows.push((r, n, t_s, cpu_all_ms, cpu_one_ms, fp16_max, fp16_mean));
        traffic_rows.push((r, t_s / n as f64, penumbra_passes::hsdt::bytes_per_map(r)));
        let Some(table) = table.as_ref() else {
            continue; // --speed-only
        };
        // HSDT against brute force: random maps + adversarial ones (up to r = 128)
        let mut check: Vec<(String, VisMap)> =
            maps.iter().take(args.verify).enumerate().map(|(i, m)| (format!("random {i}"), m.clone())).collect();
        if r <= 128 {
            check.extend(test_maps(r, args.seed));
        }
        let pb = bar(check.len() as u64, &format!("r={r}: brute-force SSDF"));
        // one map per task: brute force costs the same for every map
        let res: Vec<(f64, f64)> = par_map_each(&check, |(_, m)| {
            let e = field_error(&hsdt_f64(m), &ssdf_brute_force(m));
            pb.inc(1);
            e
        });
        pb.finish();
        let bf_max = res.iter().map(|e| e.0).fold(0.0, f64::max);
        let bf_mean = res.iter().map(|e| e.1).sum::<f64>() / res.len() as f64;
        acc_rows.push((r, check.len(), bf_max, bf_mean, h));
        // integrals against brute force over the binary map, per lambda
        let lambdas = [1e-2, 1.0, 10.0, 100.0, 1e3, 1e4];
        let nv = args.verify.min(maps.len()).max(1);
        for &lambda in &lambdas {
            let mut cases = Vec::new();
            for (mi, m) in maps.iter().take(nv).enumerate() {
                for k in 0..6u64 {
                    let mut s = args.seed ^ (k + 7 * mi as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                    let mut next = move || {
                        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        (s >> 11) as f64 / (1u64 << 53) as f64
                    };
                    let axis = match k {
                        0 => DVec3::Z,
                        1 => DVec3::new(0.15, 0.98, 0.03), // grazing
                        _ => DVec3::new(2.0 * next() - 1.0, 2.0 * next() - 1.0, next()),
                    };
                    cases.push((mi, m, Sg::new(axis.normalize(), lambda, 1.0)));
                }
            }
            let full = VisMap::filled(r, true);
            let pb = bar(cases.len() as u64, &format!("r={r} lambda={lambda}: integrals"));
            let errs: Vec<(f64, f64, f64, f64)> = par_map_each(&cases, |(mi, m, g)| {
                let view = SsdfView { r, values: &gpu[*mi] };
                let norm = brute_force(&full, g, true, false).max(1e-300);
                let bf = brute_force(m, g, true, false);
                let t0 = Instant::now();
                let c = visible_cells(&view, g, true);
                let tc = t0.elapsed().as_secs_f64();
                let norm_sg = brute_force(&full, g, true, true).max(1e-300);
                let bfa = brute_force(m, g, true, true);
                let t0 = Instant::now();
                let a = visible_axis(&view, table, g, true);
                let ta = t0.elapsed().as_secs_f64();
                pb.inc(1);
                ((a - bfa).abs() / norm_sg, (c - bf).abs() / norm, ta, tc)
            });
            pb.finish();
            let k = errs.len() as f64;
            int_rows.push((
                r,
                lambda,
                errs.iter().map(|e| e.0).sum::<f64>() / k,
                errs.iter().map(|e| e.0).fold(0.0, f64::max),
                errs.iter().map(|e| e.1).sum::<f64>() / k,
                errs.iter().map(|e| e.1).fold(0.0, f64::max),
                errs.iter().map(|e| e.2).sum::<f64>() / k * 1e6,
                errs.iter().map(|e| e.3).sum::<f64>() / k * 1e6,
            ));
        }
        // GPU time per lobe of each integral: random lobes over the maps' SSDFs
        let q = 2048u32;
        let mut lobes = Vec::with_capacity(q as usize);
        let mut params_a = Vec::with_capacity(q as usize);
        let mut s = args.seed.wrapping_add(99);
        let mut next = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for i in 0..q {
            let axis = DVec3::new(2.0 * next() - 1.0, 2.0 * next() - 1.0, next()).normalize();
            let lambda = 10f64.powf(-2.0 + 6.0 * next());
            lobes.push([axis.x as f32, axis.y as f32, axis.z as f32, lambda as f32]);
            params_a.push([1.0f32, 1.0, (i % n) as f32, 1.0]);
        }
        let ssdf_words: Vec<u32> = gpu.iter().flat_map(|v| pack_ssdf_f16(v)).collect();
        let mut integrate_run = |lobes: &[[f32; 4]], params_a: &[[f32; 4]]| -> Result<(f64, f64)> {
            let params_b: Vec<[f32; 4]> = params_a.iter().map(|p| [p[0], p[1], p[2], 2.0]).collect();
            let mut g = Graph::new();
            let sb = g.create_buffer_init("ssdf", bytes_of(&ssdf_words));
            let tb = g.create_buffer_init("table", bytes_of(&table.data));
            let lb = g.create_buffer_init("lobes", bytes_of(lobes));
            let pa = g.create_buffer_init("params_a", bytes_of(params_a));
            let pbuf = g.create_buffer_init("params_b", bytes_of(&params_b));
            let oa = integ.add(&mut g, "integrate_axis", sb, tb, lb, pa, q, r);
            let ob = integ.add(&mut g, "integrate_cells", sb, tb, lb, pbuf, q, r);
            add_copy_to_readback(&mut g, oa, "oa", q as u64 * 8);
            add_copy_to_readback(&mut g, ob, "ob", q as u64 * 8);
            engine.submit(g)?;
            let o = engine.drain()?.pop().ok_or_else(|| anyhow!("no frame output"))?;
            Ok((gpu_ms(&o, &["integrate_axis"]) * 1e3 / q as f64, gpu_ms(&o, &["integrate_cells"]) * 1e3 / q as f64))
        };
        integrate_run(&lobes, &params_a)?; // warm-up
        let (ua, ub) = integrate_run(&lobes, &params_a)?;
        // coherent order (as neighbouring pixels): sorted by map, then by sharpness
        let mut order: Vec<usize> = (0..q as usize).collect();
        order.sort_by(|&x, &y| params_a[x][2].total_cmp(&params_a[y][2]).then(lobes[x][3].total_cmp(&lobes[y][3])));
        let lobes_s: Vec<[f32; 4]> = order.iter().map(|&i| lobes[i]).collect();
        let params_s: Vec<[f32; 4]> = order.iter().map(|&i| params_a[i]).collect();
        let (ua_s, ub_s) = integrate_run(&lobes_s, &params_s)?;
        println!(
            "r={r}: GPU per lobe evaluation ({q} lobes, lambda log-uniform 1e-2..1e4, random axes): (a) axis {ua:.2} us, (b) cells {ub:.2} us; sorted by map and lambda (coherent): (a) {ua_s:.2} us, (b) {ub_s:.2} us"
        );
    }
    println!();
    println!("HSDT speed ({} maps per resolution; t_S = GPU time of the HSDT pass, timestamps)", n);
    println!(
        "{:>4} {:>12} {:>16} {:>18} {:>18} {:>9} {:>12} {:>12}",
        "r",
        "t_S us/pt",
        "t_S ms/1000 pts",
        "CPU all cores ms/1k",
        "CPU 1 core ms/1k",
        "speedup",
        "fp16 max",
        "fp16 mean"
    );
    for (r, n, t_s, ca, c1, fm, fmean) in &speed_rows {
        let per = t_s / *n as f64;
        println!(
            "{:>4} {:>12.2} {:>16.2} {:>18.2} {:>18.2} {:>9.2} {:>12.2e} {:>12.2e}",
            r,
            per * 1e3,
            per * 1e3 * 1000.0 / 1e3,
            ca / *n as f64 * 1000.0,
            c1 / *n as f64 * 1000.0,
            ca / t_s.max(1e-9),
            fm,
            fmean
        );
    }
    println!();
    let pb = bar(2, "memory bandwidth");
    let host = host_copy_bandwidth();
    pb.inc(1);
    let device = device_copy_bandwidth(&mut Engine::new(ctx.clone(), 1).map(|mut e| {
        e.timestamps = true;
        e
    })?)?;
    pb.finish();
    println!(
        "HSDT bytes moved (the pass's buffer reads and writes per map: the bits and the fp16 SSDF) against the memory bandwidth measured now (a copy of 256 MiB, read + write): host {:.2} GB/s (all cores), device {:.2} GB/s (a copy pass; a CPU driver's device memory is the host's)",
        host / 1e9,
        device / 1e9
    );
    println!("{:>4} {:>12} {:>12} {:>12} {:>10} {:>10}", "r", "t_S us/pt", "KB/pt", "GB/s", "of host", "of device");
    for (r, t, bytes) in &traffic_rows {
        let rate = *bytes as f64 / (t * 1e-3).max(1e-12);
        println!(
            "{:>4} {:>12.2} {:>12.1} {:>12.3} {:>9.1}% {:>9.1}%",
            r,
            t * 1e3,
            *bytes as f64 / 1e3,
            rate / 1e9,
            100.0 * rate / host,
            100.0 * rate / device
        );
    }
    if args.speed_only {
        return Ok(());
    }
    println!();
    println!("HSDT against the brute-force spherical distance transform (radians; texel = pi/r)");
    println!("{:>4} {:>6} {:>12} {:>12} {:>14}", "r", "maps", "max error", "mean error", "max / texel");
    for (r, k, mx, mean, h) in &acc_rows {
        println!("{:>4} {:>6} {:>12.2e} {:>12.2e} {:>14.2e}", r, k, mx, mean, mx / h);
    }
    println!();
    println!("SSDF integrals against brute force over the binary map (error / unoccluded integral; CPU us per lobe)");
    println!(
        "{:>4} {:>8} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10}",
        "r", "lambda", "(a) mean", "(a) max", "(b) mean", "(b) max", "(a) us", "(b) us"
    );
    for (r, l, am, ax, bm, bx, ta, tb) in &int_rows {
        println!("{:>4} {:>8.0e} {:>12.4} {:>12.4} {:>12.5} {:>12.5} {:>10.2} {:>10.1}", r, l, am, ax, bm, bx, ta, tb);
    }
    Ok(())
}
