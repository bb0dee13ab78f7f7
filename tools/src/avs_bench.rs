//! `penumbra bench avs [SCENE]`: the adaptive-visibility-sampling technique (issue 8) per scene in
//! the columns of the paper's Table 1 (pixels, vertices, sample points, memory, t_I, t_V, t_S,
//! ms/frame), its error against the CPU reference, the GPU Monte Carlo baseline (`mc`) at the same
//! GPU time and the time it needs to reach the same error (RMSE over the reference's mean; the
//! reference samples the pixel centres where avs's G-buffer does, and so does `mc`, unless `--aa`),
//! adaptive against brute-force
//! visibility maps at r = 64, 128, 256, and an E_v,max x r sweep (error/time), in one run.
//! Every avs measurement is the second of two frames (t - 1/30 s, t), so that G-buffer culling
//! (parameter `cull`, on by default) works from the first frame's flags; a table compares it off
//! and on, and another the integration modes (axis, cells, table; adf at sizes up to 32x24).

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::{RenderSettings, Renderer};
use penumbra_reference::cli::parse_size;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct AvsArgs {
    /// Scene file; without it the paper's three scenes (hat_on_cloth, balls_on_dish, falling).
    pub scene: Option<PathBuf>,
    /// Image size WxH.
    #[arg(long, default_value = "96x72")]
    pub size: String,
    /// Scene time measured (seconds).
    #[arg(long, default_value_t = 0.5)]
    pub time: f32,
    /// Samples per pixel of the CPU reference.
    #[arg(long, default_value_t = 32)]
    pub spp: u32,
    /// Most frames the MC baseline accumulates (4 spp each).
    #[arg(long, default_value_t = 24)]
    pub mc_frames: u32,
    /// Skip the r / E_v,max sweeps and the brute-force comparison.
    #[arg(long)]
    pub no_sweep: bool,
    /// Compare against an anti-aliased reference (a box pixel filter) and let `mc` jitter its
    /// primary rays over the pixel. Without it (default) the reference samples the pixel centres,
    /// where avs's G-buffer does (as the accuracy matrix's references), and `mc` samples them too
    /// (`aa = false`): both are then measured on their shading, not on avs's aliasing.
    #[arg(long)]
    pub aa: bool,
    /// Write each scene's reference, avs frame and `mc` image (the frame that reached avs's
    /// RMSE over the mean, or its last) as EXR under DIR/<scene>/ with false-colour difference
    /// PNGs against the reference, and DIR/avs_mc.png, a contact sheet of the three per scene.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Extra avs parameters KEY=VALUE (as --param of render).
    #[arg(long = "param")]
    pub params: Vec<String>,
    /// Also draw the E_v,max x r sweep as a chart (PNG): PSNR against ms per frame, one line per
    /// r, points labelled by E_v,max (the paper's Fig. 6 trade). Needs the sweep (no --no-sweep).
    #[arg(long)]
    pub chart: Option<PathBuf>,
}

/// One measured avs render.
struct AvsRun {
    /// Sample points of the measured frame at their positions then (the traced ones).
    sample_points: Vec<penumbra_math::avs_sampling::SurfacePoint>,
    /// GPU ms of the visibility-level passes and of the kd-tree build (measured frame).
    t_vis: f64,
    t_tree: f64,
    points: usize,
    traced: usize,
    dormant: usize,
    vertices: usize,
    rays: u64,
    map_bytes: u64,
    t_i: f64,
    t_v: f64,
    t_s: f64,
    total: f64,
    psnr: f64,
    /// RMSE over the reference's mean radiance (the error `mc` is matched to).
    rmse_mean: f64,
    rel_rmse: f64,
    /// Wall-clock ms of the measured frame's parts in the technique (`AvsStats::cpu_ms`).
    cpu_parts: Vec<(&'static str, f64)>,
    /// The measured frame.
    image: Image,
}

fn render_avs(scene: &Scene, params: &[(String, String)], w: u32, h: u32, t: f32, reference: &Image) -> Result<AvsRun> {
    let mut s = scene.clone();
    // the waited rounds: the statistics (rays, maps) and pass times are the measured frame's own
    // (the default late adaptation reports an earlier finished frame's; its frames' wall-clock
    // is in `bench matrix`)
    s.technique_params.insert("adaptation".into(), "rounds".into());
    for (k, v) in params {
        s.technique_params.insert(k.clone(), v.clone());
    }
    let settings = RenderSettings::with_technique(w, h, "avs", &s.technique_params);
    let mut r = Renderer::new_headless(&s, settings, false)?;
    // two frames (t - 1/30, t): G-buffer culling uses the previous frame's flags; the second is
    // measured
    let t0 = (t - 1.0 / 30.0).max(0.0);
    let mut frames = r.render(&s.at(t0, None), None, true)?;
    frames.extend(r.render(&s.at(t, Some(t0)), None, true)?);
    frames.extend(r.finish()?);
    let st = r.technique_stats::<penumbra_passes::avs::AvsStats>().context("avs keeps statistics")?;
    let f = frames.last().context("avs rendered no frame")?;
    let sum = |v: &[(String, f64)], pre: &[&str]| -> f64 {
        v.iter().filter(|(n, _)| pre.iter().any(|p| n.starts_with(p))).map(|(_, m)| m).sum()
    };
    // the maps are traced in waited rounds (`adaptation = rounds`, or a setup frame) or in the
    // frame's own graph (the late adaptation): both lists count
    let passes: Vec<(String, f64)> = st.round_ms.iter().chain(&f.gpu_ms).cloned().collect();
    // the SH16 passes ("avs_sh{tag}", their copies), not the shading ("avs_shade", t_I)
    let t_v = sum(&passes, &["avs_vis", "avs_sh", "kdtree"]) - sum(&passes, &["avs_shade"]);
    let t_s = sum(&f.gpu_ms, &["avs_hsdt"]);
    // the shading and its key-light filter (`key_filter`)
    let t_i = sum(&f.gpu_ms, &["avs_shade", "avs_key_filter"]);
    let total = passes.iter().map(|(_, m)| m).sum::<f64>();
    let image = crate::bench::hdr_image(f);
    let c = compare(reference, "reference", &image, "avs")?;
    let pool = penumbra_passes::avs::vertex_pool(&s, &s.at(t, Some(t0)), &st.pool_plan)?;
    Ok(AvsRun {
        sample_points: st.point_vertices.iter().map(|&v| pool[v]).collect(),
        t_vis: sum(&passes, &["avs_vis"]),
        t_tree: sum(&passes, &["kdtree"]),
        points: st.points,
        traced: st.traced_points,
        dormant: st.dormant,
        vertices: st.vertices,
        rays: st.rays,
        map_bytes: st.map_bytes + st.ssdf_bytes,
        t_i,
        t_v,
        t_s,
        total,
        psnr: c.psnr_db.unwrap_or(f64::INFINITY),
        rmse_mean: c.rmse_rel_mean,
        rel_rmse: c.rel_rmse,
        cpu_parts: st.cpu_ms.clone(),
        image,
    })
}

/// The MC baseline: (PSNR, RMSE over the reference's mean, frames) at the avs time, the ms and
/// frames it takes to reach avs's RMSE over the mean, and its last frame's.
struct McRun {
    at_time: Option<(f64, f64, u32)>,
    to_error: Option<(f64, u32)>,
    /// The same for avs's relRMSE (a per-pixel relative error that weighs dark pixels most).
    to_rel: Option<(f64, u32)>,
    last: (f64, f64, u32),
    /// The frame that reached avs's RMSE over the mean (or the last), with its RMSE over the mean.
    image: Option<(Image, f64)>,
}

/// What `mc` is measured against: avs's GPU ms per frame and RMSE over the reference's mean.
struct McTarget {
    avs_ms: f64,
    avs_rmse_mean: f64,
    avs_rel_rmse: f64,
}

fn render_mc(
    scene: &Scene,
    w: u32,
    h: u32,
    t: f32,
    frames: u32,
    aa: bool,
    reference: &Image,
    target: McTarget,
) -> Result<McRun> {
    // 4 samples per pixel per frame (mc's default until session 48): the curve's steps as the
    // README's tables measured them
    let params: penumbra_passes::registry::Params =
        [("aa".to_string(), aa.to_string()), ("spp".to_string(), "4".to_string())].into_iter().collect();
    let settings = RenderSettings::with_technique(w, h, "mc", &params);
    let mut r = Renderer::new_headless(scene, settings, false)?;
    // A warm-up frame first, left out of the curve: lavapipe compiles a shader at its first
    // dispatch, inside the pass's timestamps (mc's took 13.9 s with a cold shader cache, which
    // made a session-42 run report mc 6x slower); the first measured frame is marked as a camera
    // move, so mc restarts its accumulation there and the curve starts from zero samples.
    let mut out = r.render(&scene.at(t, None), None, true)?;
    let mut prev = None;
    for _ in 0..frames.max(1) {
        let mut f = scene.at(t, prev);
        f.camera_moved |= prev.is_none();
        out.extend(r.render(&f, None, true)?);
        prev = Some(t);
    }
    out.extend(r.finish()?);
    if out.len() != frames.max(1) as usize + 1 {
        anyhow::bail!("mc returned {} frames for {} and a warm-up", out.len(), frames.max(1));
    }
    out.remove(0);
    let mut cum = 0.0;
    let mut run = McRun { at_time: None, to_error: None, to_rel: None, last: (0.0, 0.0, 0), image: None };
    for (k, f) in out.iter().enumerate() {
        cum += f.gpu_ms.iter().map(|(_, m)| m).sum::<f64>();
        let image = crate::bench::hdr_image(f);
        let c = compare(reference, "reference", &image, "mc")?;
        let psnr = c.psnr_db.unwrap_or(f64::INFINITY);
        let frames = k as u32 + 1;
        if run.at_time.is_none() && cum >= target.avs_ms {
            run.at_time = Some((psnr, c.rmse_rel_mean, frames));
        }
        if run.to_error.is_none() {
            if c.rmse_rel_mean <= target.avs_rmse_mean {
                run.to_error = Some((cum, frames));
            }
            run.image = Some((image, c.rmse_rel_mean));
        }
        if run.to_rel.is_none() && c.rel_rmse <= target.avs_rel_rmse {
            run.to_rel = Some((cum, frames));
        }
        run.last = (psnr, c.rmse_rel_mean, frames);
    }
    Ok(run)
}

fn kv(params: &[String]) -> Result<Vec<(String, String)>> {
    params
        .iter()
        .map(|p| {
            p.split_once('=')
                .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
                .ok_or_else(|| anyhow::anyhow!("--param '{p}': expected KEY=VALUE"))
        })
        .collect()
}

pub fn run(args: &AvsArgs, load: impl Fn(&Path) -> Result<Scene>) -> Result<()> {
    let (w, h) = parse_size(&args.size)?;
    if args.chart.is_some() && args.no_sweep {
        return Err(crate::bad("--chart draws the sweep: it cannot go with --no-sweep"));
    }
    let base = kv(&args.params)?;
    // the parameters are checked before anything is rendered
    let mut check = std::collections::BTreeMap::new();
    for (k, v) in &base {
        check.insert(k.clone(), v.clone());
    }
    penumbra_passes::avs::AvsSettings::from_params(&check)?;
    let scenes: Vec<PathBuf> = match &args.scene {
        Some(p) => vec![p.clone()],
        None => ["hat_on_cloth.toml", "balls_on_dish.toml", "falling.toml"]
            .iter()
            .map(|n| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(n))
            .collect(),
    };
    println!(
        "## Table 1 (size {w}x{h}, t = {} s, reference {} spp {}, avs parameters: {:?})",
        args.time,
        args.spp,
        if args.aa { "anti-aliased, mc aa = true" } else { "at the pixel centres, mc aa = false" },
        base
    );
    println!("| scene | #pixels | #verts | #samples | maps+SSDF MB | t_I ms | t_V ms | t_S ms | ms/frame | rays | PSNR dB | rmse/mean | relRMSE | MC same time: PSNR / rmse/mean (frames) | MC to same rmse/mean: ms (frames) | MC to same relRMSE |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut first: Option<(Scene, Image)> = None;
    let mut cull_rows = Vec::new();
    let mut part_rows = Vec::new();
    // --out's contact sheet: per scene the reference, avs's frame and mc's
    type Tile = (String, Option<Image>, String, Option<bool>);
    let mut sheet: Vec<(String, Vec<Tile>)> = Vec::new();
    for path in &scenes {
        let scene = load(path)?;
        let opts = ReferenceOptions {
            width: w,
            height: h,
            spp: args.spp,
            time: Some(args.time),
            mode: Mode::Exact,
            progress: true,
            pixel_grid: if args.aa { 0 } else { 1 },
            ..Default::default()
        };
        let reference = reference_render(&scene, &opts)?.radiance;
        let a = render_avs(&scene, &base, w, h, args.time, &reference)?;
        let target = McTarget { avs_ms: a.total, avs_rmse_mean: a.rmse_mean, avs_rel_rmse: a.rel_rmse };
        let mc = render_mc(&scene, w, h, args.time, args.mc_frames, args.aa, &reference, target)?;
        if let Some(dir) = &args.out {
            let d = dir.join(&scene.name);
            std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
            reference.write_exr(d.join("reference.exr"))?;
            a.image.write_exr(d.join("avs.exr"))?;
            penumbra_reference::metrics::write_diff_png(&reference, &a.image, &d.join("avs_diff.png"))?;
            let mut tiles = vec![
                ("reference".to_string(), Some(reference.clone()), format!("{} spp", args.spp), None),
                (
                    "avs".to_string(),
                    Some(a.image.clone()),
                    format!("rmse/mean {:.4}, {:.0} ms", a.rmse_mean, a.total),
                    None,
                ),
            ];
            if let Some((m, m_rmse)) = &mc.image {
                m.write_exr(d.join("mc.exr"))?;
                penumbra_reference::metrics::write_diff_png(&reference, m, &d.join("mc_diff.png"))?;
                let frames = mc.to_error.map_or(mc.last.2, |(_, f)| f);
                tiles.push((
                    "mc".to_string(),
                    Some(m.clone()),
                    format!("rmse/mean {:.4}, {frames} frames", m_rmse),
                    None,
                ));
            }
            sheet.push((scene.name.clone(), tiles));
        }
        let same = mc
            .at_time
            .map_or(format!("not reached in {} frames", mc.last.2), |(p, r, f)| format!("{p:.2} / {r:.4} ({f})"));
        let reach = mc.to_error.map_or(
            format!("not reached in {} frames (last {:.2} dB / {:.4})", mc.last.2, mc.last.0, mc.last.1),
            |(ms, f)| format!("{ms:.0} ({f}), {:.3}x the avs time", ms / a.total.max(1e-9)),
        );
        let reach_rel = mc.to_rel.map_or(format!("not reached in {} frames", mc.last.2), |(ms, f)| {
            format!("{ms:.0} ({f}), {:.3}x", ms / a.total.max(1e-9))
        });
        println!(
            "| {} | {} | {} | {} | {:.2} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {:.2} | {:.4} | {:.3} | {} | {} | {} |",
            scene.name,
            w * h,
            a.vertices,
            a.points,
            a.map_bytes as f64 / 1048576.0,
            a.t_i,
            a.t_v,
            a.t_s,
            a.total,
            a.rays,
            a.psnr,
            a.rmse_mean,
            a.rel_rmse,
            same,
            reach,
            reach_rel
        );
        part_rows.push(format!(
            "| {} | {} | {:.1} |",
            scene.name,
            a.cpu_parts.iter().map(|(_, ms)| format!("{ms:.1}")).collect::<Vec<_>>().join(" | "),
            a.cpu_parts.iter().map(|(_, ms)| ms).sum::<f64>()
        ));
        if part_rows.len() == 1 {
            part_rows.insert(
                0,
                format!(
                    "| scene | {} | sum |\n|---|{}---|",
                    a.cpu_parts.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(" | "),
                    "---|".repeat(a.cpu_parts.len())
                ),
            );
        }
        let mut p = base.clone();
        p.push(("cull".into(), "false".into()));
        let off = render_avs(&scene, &p, w, h, args.time, &reference)?;
        cull_rows.push(format!(
            "| {} | {} | {} / {} | {:.1} / {:.1} | {:.1} / {:.1} | {} / {} | {:.2} / {:.2} | {:.3} / {:.3} |",
            scene.name,
            a.dormant,
            off.traced,
            a.traced,
            off.t_v,
            a.t_v,
            off.t_s,
            a.t_s,
            off.rays,
            a.rays,
            off.psnr,
            a.psnr,
            off.rel_rmse,
            a.rel_rmse
        ));
        if first.is_none() {
            first = Some((scene, reference));
        }
    }
    println!(
        "\nt_I, t_V, t_S, ms/frame and the MC columns are GPU ms (timestamps); the wall-clock parts of \
         the measured frame inside the technique, CPU work and waits for its own submissions (the \
         adaptation rounds), in ms (`AvsStats::cpu_ms`):\n"
    );
    for r in &part_rows {
        println!("{r}");
    }
    if let Some(dir) = &args.out {
        let path = dir.join("avs_mc.png");
        crate::matrix::contact_sheet(&path, &sheet, w, h)?;
        println!(
            "\nwrote {} (per scene: reference, avs, mc at avs's error) and per-scene EXRs and difference PNGs",
            path.display()
        );
    }
    println!("\n## G-buffer culling (section 6 \"Optimization\"), second frame; each cell: off / on");
    println!("| scene | dormant points (on) | maps traced | t_V ms | t_S ms | rays | PSNR dB | relRMSE |");
    println!("|---|---|---|---|---|---|---|---|");
    for row in &cull_rows {
        println!("{row}");
    }
    if let Some((scene, reference)) = &first {
        // adf (part A's adaptive cells per pixel and lobe) costs about a millisecond per lobe on
        // lavapipe: only at tiny sizes
        let modes: &[&str] =
            if w * h <= 32 * 24 { &["axis", "cells", "table", "adf"] } else { &["axis", "cells", "table"] };
        println!(
            "\n## Integration modes on {} (second frame; t_I = the avs_shade and avs_key_filter passes)",
            scene.name
        );
        println!("| integration | t_I ms | PSNR dB | relRMSE |");
        println!("|---|---|---|---|");
        for mode in modes {
            let mut p = base.clone();
            p.push(("integration".into(), mode.to_string()));
            let a = render_avs(scene, &p, w, h, args.time, reference)?;
            println!("| {mode} | {:.1} | {:.2} | {:.3} |", a.t_i, a.psnr, a.rel_rmse);
        }
    }
    if args.no_sweep {
        return Ok(());
    }
    let (scene, reference) = first.context("no scene")?;
    println!(
        "\n## Visibility maps on {}: adaptive vs every texel traced (t_V = visibility passes of all rounds)",
        scene.name
    );
    println!("| r | adaptive t_V ms | rays | brute force t_V ms | rays | ratio |");
    println!("|---|---|---|---|---|---|");
    let mut fig7 = Vec::new();
    let ctx = penumbra::engine::Context::new(&Default::default())?;
    println!("device: {} ({})", ctx.device_name, ctx.driver_info());
    let lib = penumbra::shader_library();
    let hc = penumbra_passes::avs::hemicube::HemicubeMaps::new(&ctx, &lib)?;
    let mut engine = penumbra::engine::Engine::new(ctx.clone(), 1)?;
    engine.timestamps = true;
    for r in [64u32, 128, 256] {
        let mut p = base.clone();
        p.push(("r".into(), r.to_string()));
        p.push(("iterations".into(), "0".into()));
        let ad = render_avs(&scene, &p, w, h, args.time, &reference)?;
        // Fig. 7: the same points' maps by rasterized hemicubes (warm-up run, then the measured one)
        let t0 = (args.time - 1.0 / 30.0).max(0.0);
        let frame = scene.at(args.time, Some(t0));
        let (tris, _, no_shadow) = penumbra_passes::kdtree::world_triangles_shading(&scene, &frame)?;
        let tris: Vec<[glam::Vec3; 3]> = tris.iter().zip(&no_shadow).filter(|(_, ns)| !**ns).map(|(t, _)| *t).collect();
        let pool = penumbra_passes::avs::vertex_pool(
            &scene,
            &frame,
            &penumbra_passes::avs::PoolPlan::vertices_only(&scene, &frame)?,
        )?;
        let offset = penumbra_passes::avs::ray_offset(&pool);
        hc.run(&mut engine, &tris, &ad.sample_points, offset, r, false)?;
        let hr = hc.run(&mut engine, &tris, &ad.sample_points, offset, r, false)?;
        let ms = |pre: &str| hr.gpu_ms.iter().filter(|(n, _)| n.starts_with(pre)).map(|(_, m)| m).sum::<f64>();
        let (raster, convert) = (ms("avs_hc_raster"), ms("avs_hc_convert"));
        fig7.push(format!(
            "| {r} | {} | {:.1} | {:.1} | {:.1} | {} | {:.1} | {:.1} | {:.1} | {:.2} |",
            ad.sample_points.len(),
            ad.t_vis,
            ad.t_tree,
            ad.t_vis + ad.t_tree,
            HemicubeFace(r),
            raster,
            convert,
            raster + convert,
            (raster + convert) / (ad.t_vis + ad.t_tree).max(1e-9)
        ));
        p.push(("adaptive".into(), "false".into()));
        let bf = render_avs(&scene, &p, w, h, args.time, &reference)?;
        println!(
            "| {r} | {:.1} | {} | {:.1} | {} | {:.2} |",
            ad.t_v,
            ad.rays,
            bf.t_v,
            bf.rays,
            bf.t_v / ad.t_v.max(1e-9)
        );
    }
    println!(
        "\n## Fig. 7 on {}: visibility-map generation, this method vs rasterized hemicubes (shadow maps), same sample points (second frame, culled), {} triangles",
        scene.name,
        penumbra_passes::kdtree::world_triangles_shading(&scene, &scene.at(args.time, None))?.0.len()
    );
    println!("| r | points | avs vis passes ms | kd-tree build ms | avs total ms | hemicube faces | raster ms | convert ms | shadow maps total ms | shadow maps / avs |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for row in &fig7 {
        println!("{row}");
    }
    drop(engine);
    println!("\n## E_v,max x r on {} (error / time)", scene.name);
    println!("| r | E_v,max | #samples | ms/frame | PSNR dB | relRMSE |");
    println!("|---|---|---|---|---|---|");
    let mut series = Vec::new();
    for r in [64u32, 128] {
        let mut line = crate::plot::Series { name: format!("r = {r}"), ..Default::default() };
        for e in ["0.20", "0.10", "0.05"] {
            let mut p = base.clone();
            p.push(("r".into(), r.to_string()));
            p.push(("e_max".into(), e.into()));
            p.push(("e_min".into(), format!("{}", e.parse::<f32>().unwrap_or(0.1) / 2.0)));
            let a = render_avs(&scene, &p, w, h, args.time, &reference)?;
            println!("| {r} | {e} | {} | {:.1} | {:.2} | {:.3} |", a.points, a.total, a.psnr, a.rel_rmse);
            line.points.push((a.total, a.psnr));
            line.labels.push(format!(" E={e}"));
        }
        series.push(line);
    }
    if let Some(path) = &args.chart {
        let chart = crate::plot::Chart::new(
            format!("{}: avs error against time (E_v,max x r), {w}x{h}", scene.name),
            "ms per frame (second frame, lavapipe)",
            format!("PSNR vs reference, {} spp (dB)", args.spp),
        )
        .log(true, false);
        crate::plot::write_chart(path, &chart, &series)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Hemicube face description for the Fig. 7 table.
struct HemicubeFace(u32);

impl std::fmt::Display for HemicubeFace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let fr = penumbra_passes::avs::hemicube::HemicubeMaps::face_res(self.0);
        write!(f, "5 x {fr}^2 (sides half)")
    }
}
