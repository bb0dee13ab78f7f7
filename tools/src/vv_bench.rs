//! `penumbra bench vv SCENE|MODEL.glb`: the previous vectorized-visibility method (eq. 19, three
//! evaluations) against the interpolated one (eq. 21, one evaluation), under dynamic tessellation
//! for zeta = 1..4 and per fragment: GPU ms per frame (sum of the pass medians), their ratio,
//! PSNR against the CPU reference for both, triangles after tessellation (pipeline statistics),
//! and the precompute time and memory, in one run. Writes `vv_bench.json`, the images and
//! `vv_tradeoff.png` (PSNR against ms per method, points labelled by zeta).

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::{RenderSettings, Renderer};
use penumbra_passes::vv::{VvSceneData, VvStats};
use penumbra_reference::cli::parse_size;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct VvArgs {
    /// A scene file or a bare glTF model (.glb/.gltf).
    pub scene: PathBuf,
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Frames rendered per configuration (timings are medians over them).
    #[arg(long, default_value_t = 4)]
    pub frames: u32,
    /// Reference samples per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Largest zeta (tessellation quality) measured, from 1.
    #[arg(long, default_value_t = 4)]
    pub max_zeta: u32,
    /// SAT map width.
    #[arg(long, default_value_t = 256)]
    pub sat_width: u32,
    /// Visibility-map resolution of the precompute.
    #[arg(long, default_value_t = 64)]
    pub resolution: u32,
    /// Receiver refinement (the technique's `refine`: about this many vertices over the scene's
    /// area; 0 = the meshes as given, as the paper's coarse models).
    #[arg(long, default_value_t = 1024)]
    pub refine: u32,
    /// Largest tessellation level.
    #[arg(long, default_value_t = 64)]
    pub max_level: u32,
    #[arg(long, default_value = "out/bench-vv")]
    pub out: PathBuf,
}

struct Row {
    config: String,
    ms: f64,
    psnr: f64,
    triangles: Option<u64>,
}

pub fn run(args: &VvArgs, scene: &Scene) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let opts = ReferenceOptions {
        width,
        height,
        spp: args.spp,
        time: Some(0.0),
        mode: Mode::Exact,
        progress: true,
        ..Default::default()
    };
    let reference = crate::bench::reference_into(scene, &opts, &args.out)?;
    let data = VvSceneData::cached(scene, args.resolution, args.refine)?;
    println!(
        "precompute: {} vertices, {} triangles; visibility {:.2} s, {:.2} MB; correspondence {}",
        data.model().positions.len(),
        data.model().triangle_count(),
        data.visibility_seconds,
        data.visibility_bytes as f64 / 1e6,
        if data.corr.is_some() {
            format!("{:.2} s, {:.2} MB", data.correspondence_seconds, data.triple_bytes as f64 / 1e6)
        } else {
            "not available".into()
        }
    );
    let mut configs: Vec<(String, Vec<(&str, String)>)> = Vec::new();
    for z in 1..=args.max_zeta.max(1) {
        for mode in ["tessellation3", "tessellation"] {
            configs.push((format!("{mode} zeta={z}"), vec![("mode", mode.to_string()), ("zeta", z.to_string())]));
        }
    }
    for mode in ["fragment3", "fragment1"] {
        configs.push((mode.to_string(), vec![("mode", mode.to_string())]));
    }
    let mut rows = Vec::new();
    let mut device: Option<(String, String)> = None;
    for (name, params) in &configs {
        let mut s = scene.clone();
        s.technique = "vv".into();
        s.technique_params.clear();
        for (k, v) in params {
            s.technique_params.insert(k.to_string(), v.clone());
        }
        s.technique_params.insert("sat_width".into(), args.sat_width.to_string());
        s.technique_params.insert("resolution".into(), args.resolution.to_string());
        s.technique_params.insert("refine".into(), args.refine.to_string());
        s.technique_params.insert("max_level".into(), args.max_level.to_string());
        let settings = penumbra_passes::vv::VvSettings::from_params(&s.technique_params)?;
        let ctx = penumbra::engine::Context::new(&Default::default())?;
        let shaders = penumbra::shader_library();
        // a cheap check of the configuration (no raster pipeline: the renderer builds its own)
        let tech = match penumbra_passes::vv::VvTechnique::sat_only(&ctx, &shaders, &s, settings) {
            Ok(t) => t,
            Err(e) => {
                println!("{name:<22} skipped: {e:#}");
                continue;
            }
        };
        drop(tech);
        let rs = RenderSettings::with_technique(width, height, "vv", &s.technique_params);
        let mut r = Renderer::new(ctx, &s, rs)?;
        device.get_or_insert_with(|| (r.context().device_name.clone(), r.context().driver_info()));
        let frame = s.at(0.0, Some(0.0));
        let mut images = Vec::new();
        for _ in 0..args.frames.max(2) {
            images.extend(r.render(&frame, None, true)?);
        }
        images.extend(r.finish()?);
        let img = crate::bench::hdr_image(images.last().context("no frame finished")?);
        img.write_exr(args.out.join(format!("{}.exr", name.replace([' ', '='], "_"))))?;
        let c = compare(&reference.radiance, "reference", &img, name)?;
        let stats = r.engine.profiler.gpu_stats();
        let ms: f64 = stats.iter().filter(|(p, _)| p.starts_with("vv_")).map(|(_, s)| s.median_ms).sum();
        // the last finished frame's pipeline statistics (the renderer has finished its frames)
        let tris = r.technique_stats::<VvStats>().and_then(|st| st.tessellated_triangles);
        drop(r);
        let psnr = c.psnr_db.unwrap_or(f64::INFINITY);
        println!(
            "{name:<22} {ms:>9.2} ms/frame  PSNR {psnr:>6.2}  triangles {}",
            tris.map_or("-".into(), |t| t.to_string())
        );
        rows.push(Row { config: name.clone(), ms, psnr, triangles: tris });
    }
    println!("\n| config | previous (eq. 19) ms | this (eq. 21) ms | ratio | PSNR prev | PSNR this | triangles prev | triangles this |");
    println!("|---|---|---|---|---|---|---|---|");
    let find = |n: &str| rows.iter().find(|r| r.config == n);
    let mut pairs = Vec::new();
    for z in 1..=args.max_zeta.max(1) {
        pairs.push((format!("zeta={z}"), format!("tessellation3 zeta={z}"), format!("tessellation zeta={z}")));
    }
    pairs.push(("per fragment".into(), "fragment3".into(), "fragment1".into()));
    let mut json = Vec::new();
    for (label, a, b) in &pairs {
        let (ra, rb) = (find(a), find(b));
        let f = |r: Option<&Row>, g: &dyn Fn(&Row) -> String| r.map_or("-".into(), g);
        let ratio = match (ra, rb) {
            (Some(x), Some(y)) if y.ms > 0.0 => format!("{:.2}", x.ms / y.ms),
            _ => "-".into(),
        };
        println!(
            "| {label} | {} | {} | {ratio} | {} | {} | {} | {} |",
            f(ra, &|r| format!("{:.2}", r.ms)),
            f(rb, &|r| format!("{:.2}", r.ms)),
            f(ra, &|r| format!("{:.2}", r.psnr)),
            f(rb, &|r| format!("{:.2}", r.psnr)),
            f(ra, &|r| r.triangles.map_or("-".into(), |t| t.to_string())),
            f(rb, &|r| r.triangles.map_or("-".into(), |t| t.to_string())),
        );
        json.push(serde_json::json!({
            "config": label,
            "previous": ra.map(|r| serde_json::json!({"ms": r.ms, "psnr_db": r.psnr, "triangles": r.triangles})),
            "interpolated": rb.map(|r| serde_json::json!({"ms": r.ms, "psnr_db": r.psnr, "triangles": r.triangles})),
        }));
    }
    let body = serde_json::json!({
        "reference": {"spp": args.spp, "seconds": reference.render_seconds},
        "precompute": {
            "vertices": data.model().positions.len(),
            "triangles": data.model().triangle_count(),
            "visibility_seconds": data.visibility_seconds,
            "visibility_bytes": data.visibility_bytes,
            "correspondence_seconds": data.correspondence_seconds,
            "triple_bytes": data.triple_bytes,
        },
        "rows": json,
    });
    crate::bench::write_report(&args.out.join("vv_bench.json"), device, &scene.name, [width, height], body)?;
    // Fig. 11's comparison as a picture: per method, PSNR against ms over zeta and per fragment.
    let method = |name: &str, pick: &dyn Fn(&(String, String, String)) -> &String| {
        let (points, labels) = pairs
            .iter()
            .filter_map(|p| find(pick(p)).map(|r| ((r.ms, r.psnr), format!(" {}", p.0.replace("zeta=", "z")))))
            .unzip();
        crate::plot::Series { name: name.into(), points, labels }
    };
    let series = [method("previous (eq. 19)", &|p| &p.1), method("this paper (eq. 21)", &|p| &p.2)];
    let chart = crate::plot::Chart::new(
        format!("{}: vv error against time, {width}x{height}", scene.name),
        "GPU ms per frame (median, lavapipe)",
        format!("PSNR vs reference, {} spp (dB)", args.spp),
    )
    .log(true, false);
    let path = args.out.join("vv_tradeoff.png");
    match crate::plot::write_chart(&path, &chart, &series) {
        Ok(()) => println!("wrote {}", path.display()),
        Err(e) => println!("no chart: {e:#}"),
    }
    Ok(())
}
