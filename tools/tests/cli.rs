//! The `penumbra` binary: outputs, dumps, exit codes and messages on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;
use common::{text, tmp};

/// The binary under test: `PENUMBRA_BIN` when set (to run these tests against another build,
/// e.g. `PENUMBRA_BIN=$PWD/target/release/penumbra`), else the one cargo built for this test
/// (what scripts/test.sh runs: the test profile keeps overflow checks on, so arithmetic that
/// a release build would wrap on hostile inputs panics here and fails the test).
fn penumbra(args: &[&str]) -> Output {
    let bin =
        std::env::var_os("PENUMBRA_BIN").map_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_penumbra")), PathBuf::from);
    Command::new(&bin).args(args).output().unwrap_or_else(|e| panic!("run {}: {e}", bin.display()))
}

#[test]
fn render_default_scene_writes_frames_dumps_and_profile() {
    let out = tmp("render_default");
    let o = penumbra(&[
        "render",
        "--size",
        "64x48",
        "--frames",
        "2",
        "--out",
        out.to_str().unwrap(),
        "--validate",
        "--profile",
        "--dump-graph",
        "--dump-passes",
        "--trace",
        out.join("trace.json").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    for f in [
        "frame_0000.exr",
        "frame_0000.png",
        "frame_0001.exr",
        "frame_0001.png",
        "graph.json",
        "graph.dot",
        "graph.txt",
        "graph.html",
        "profile.json",
        "profile.png",
    ] {
        assert!(out.join(f).exists(), "missing {f}");
    }
    for f in ["gb_position", "gb_normal", "gb_uv_mat", "gb_motion", "gb_depth", "hdr"] {
        assert!(out.join(format!("passes/frame_0001_{f}.exr")).exists(), "missing pass dump {f}");
    }
    let t = text(&o);
    assert!(t.contains("validation: 0 error(s)"), "{t}");
    assert!(t.contains("gbuffer") && t.contains("median ms"), "{t}");
    let graph: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("graph.json")).unwrap()).unwrap();
    let passes: Vec<_> =
        graph["passes"].as_array().unwrap().iter().map(|p| p["name"].as_str().unwrap().to_string()).collect();
    // the default scene's technique is `auto`: shadowmaps, its depth maps kept from frame 0
    assert_eq!(passes, ["gbuffer", "shadowmaps_shade", "tonemap", "dump_passes", "readback"]);
    assert!(graph["passes"][0]["gpu_ms"]["median"].as_f64().unwrap() > 0.0);
    // graph.html: a row and a timeline bar per pass, the final image and the six dumped ones as
    // embedded thumbnails, nothing fetched; in a headless Chromium when one is installed.
    let html = std::fs::read_to_string(out.join("graph.html")).unwrap();
    for p in &passes {
        assert!(html.contains(&format!("data-pass=\"{p}\">")), "graph.html has no row for {p}");
    }
    assert_eq!(html.matches("<rect class=\"bar\"").count(), passes.len());
    assert_eq!(html.matches("<img class=\"thumb\"").count(), 7, "ldr and the six dumps");
    assert!(html.contains("alt=\"gb_normal\"") && html.contains("alt=\"ldr\""));
    assert!(!html.contains("http://") && !html.contains("https://"));
    headless_browser_shows(&out.join("graph.html"), &passes);
    let profile: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("profile.json")).unwrap()).unwrap();
    assert_eq!(profile["frames"], 2);
    // The Chrome trace: both frames' CPU spans on the CPU tracks, every live pass of each frame
    // on the GPU track, GPU frames in order and not overlapping.
    let trace: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("trace.json")).unwrap()).unwrap();
    let ev = trace["traceEvents"].as_array().unwrap();
    let spans =
        |cat: &str| -> Vec<&serde_json::Value> { ev.iter().filter(|e| e["ph"] == "X" && e["cat"] == cat).collect() };
    for name in ["build graph", "technique", "graph compile", "record", "queue submit", "fence wait"] {
        let n = spans("cpu").iter().filter(|e| e["name"] == name).count();
        assert_eq!(n, 2, "{name}: {n} spans");
    }
    let gpu = spans("gpu");
    for frame in [0, 1] {
        let names: Vec<&str> =
            gpu.iter().filter(|e| e["args"]["frame"] == frame).map(|e| e["name"].as_str().unwrap()).collect();
        assert!(names.contains(&"gbuffer") && names.contains(&"tonemap"), "frame {frame}: {names:?}");
    }
    let end0 = gpu
        .iter()
        .filter(|e| e["args"]["frame"] == 0)
        .map(|e| e["ts"].as_f64().unwrap() + e["dur"].as_f64().unwrap())
        .fold(0.0, f64::max);
    let start1 =
        gpu.iter().filter(|e| e["args"]["frame"] == 1).map(|e| e["ts"].as_f64().unwrap()).fold(f64::INFINITY, f64::min);
    assert!(start1 >= end0 - 1e-6, "frame 1's GPU work starts after frame 0's: {start1} < {end0}");
    assert!(ev.iter().all(|e| e["ph"] != "X" || e["dur"].as_f64().unwrap() >= 0.0));
}

fn expect_bad_input(args: &[&str], needles: &[&str]) {
    let o = penumbra(args);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "args {args:?}: {t}");
    assert!(!t.contains("panicked"), "{t}");
    for n in needles {
        assert!(t.contains(n), "args {args:?}: expected '{n}' in: {t}");
    }
}

#[test]
fn bad_input_exits_2_with_the_file_and_problem() {
    let d = tmp("bad_input");
    let missing = d.join("nope.toml");
    expect_bad_input(
        &["render", missing.to_str().unwrap(), "--out", d.to_str().unwrap()],
        &["nope.toml", "cannot read"],
    );
    let broken = d.join("broken.toml");
    std::fs::write(&broken, "[camera]\neye = [0, 1, 2]\nbogus_key = 3\n").unwrap();
    expect_bad_input(&["render", broken.to_str().unwrap(), "--out", d.to_str().unwrap()], &["broken.toml", "line"]);
    let glb = d.join("truncated.glb");
    std::fs::write(&glb, b"glTF\x02\x00\x00\x00garbage").unwrap();
    expect_bad_input(&["render", glb.to_str().unwrap(), "--out", d.to_str().unwrap()], &["truncated.glb"]);
    // The Draco bunny with its compressed stream damaged (the intact file renders).
    let mut draco =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/bunny-draco.glb")).unwrap();
    let json_len = u32::from_le_bytes(draco[12..16].try_into().unwrap()) as usize;
    let len = draco.len();
    draco[20 + json_len + 16..len].fill(0xA5);
    let damaged = d.join("damaged-draco.glb");
    std::fs::write(&damaged, &draco).unwrap();
    expect_bad_input(
        &["render", damaged.to_str().unwrap(), "--out", d.to_str().unwrap()],
        &["damaged-draco.glb", "KHR_draco_mesh_compression", "cannot be decoded"],
    );
    expect_bad_input(
        &["render", "--technique", "nope", "--out", d.to_str().unwrap()],
        &["unknown technique 'nope'", "registered", "avs"],
    );
    // the scene file names a technique the registry does not have
    let tech = d.join("tech.toml");
    std::fs::write(&tech, "technique = \"hsdt\"\n[camera]\neye = [0, 1, 2]\ntarget = [0, 0, 0]\n[[object]]\nmesh = { type = \"cube\", size = 1 }\n").unwrap();
    expect_bad_input(
        &["render", tech.to_str().unwrap(), "--out", d.to_str().unwrap()],
        &["tech.toml", "unknown technique 'hsdt'"],
    );
    expect_bad_input(
        &["render", "--technique", "env", "--param", "lobes=8", "--out", d.to_str().unwrap()],
        &["env", "takes no parameters"],
    );
    expect_bad_input(
        &["render", "--technique", "isg", "--param", "bogus=1", "--size", "16x12", "--out", d.to_str().unwrap()],
        &["unknown isg parameter 'bogus'"],
    );
    expect_bad_input(
        &["render", "--technique", "isg", "--param", "lobes=many", "--size", "16x12", "--out", d.to_str().unwrap()],
        &["lobes", "many"],
    );
    // every bad parameter is named, not only the first
    expect_bad_input(
        &[
            "render",
            "--technique",
            "vv",
            "--param",
            "zeta=-1",
            "--param",
            "arcs=x",
            "--size",
            "16x12",
            "--out",
            d.to_str().unwrap(),
        ],
        &["2 bad technique parameters", "zeta", "arcs"],
    );
    expect_bad_input(
        &["bench", "avs", "--no-sweep", "--chart", d.join("c.png").to_str().unwrap()],
        &["--chart", "--no-sweep"],
    );
    expect_bad_input(&["render", "--param", "novalue", "--out", d.to_str().unwrap()], &["KEY=VALUE"]);
    expect_bad_input(&["render", "--size", "0x10", "--out", d.to_str().unwrap()], &["size"]);
    expect_bad_input(&["render", "--size", "abc", "--out", d.to_str().unwrap()], &["size"]);
    expect_bad_input(&["compare", missing.to_str().unwrap(), missing.to_str().unwrap()], &["nope.toml"]);
    let not_exr = d.join("x.exr");
    std::fs::write(&not_exr, b"not an exr").unwrap();
    expect_bad_input(&["compare", not_exr.to_str().unwrap(), not_exr.to_str().unwrap()], &["x.exr"]);
}

/// Hostile sizes (issue 25): refused before allocating, exit 2, the file named. The loaders'
/// own tests (`scene/tests/limits.rs`) cover each class; here the CLI's codes and flags.
#[test]
fn hostile_sizes_exit_2_before_allocating() {
    let d = tmp("hostile");
    let out = d.join("out");
    // a 500-byte glTF whose sparse POSITION claims 2e9 vertices (24 GB)
    let sparse = d.join("sparse.gltf");
    std::fs::write(
        &sparse,
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA"}],
"bufferViews":[{"buffer":0,"byteLength":12}],
"accessors":[{"componentType":5126,"count":2000000000,"type":"VEC3","max":[1,1,1],"min":[0,0,0],
"sparse":{"count":1,"indices":{"bufferView":0,"componentType":5125},"values":{"bufferView":0}}}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#,
    )
    .unwrap();
    expect_bad_input(
        &["render", sparse.to_str().unwrap(), "--out", out.to_str().unwrap()],
        &["sparse.gltf", "too large", "--memory-budget"],
    );
    // a Radiance header claiming 100000 x 100000
    std::fs::write(d.join("huge.hdr"), b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n\0\0\0\0").unwrap();
    let env = d.join("env.toml");
    std::fs::write(&env, "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[environment]\nfile = \"huge.hdr\"\n")
        .unwrap();
    expect_bad_input(
        &["render", env.to_str().unwrap(), "--out", out.to_str().unwrap()],
        &["huge.hdr", "100000x100000"],
    );
    // a real scene over a 1 MiB budget: the flag is honoured and named
    let falling = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/falling.toml");
    expect_bad_input(
        &["render", falling.to_str().unwrap(), "--memory-budget", "1", "--out", out.to_str().unwrap()],
        &["too large", "budget of 1.0 MiB"],
    );
    expect_bad_input(&["render", "--size", "20000x10", "--out", out.to_str().unwrap()], &["20000x10"]);
    // a RenderDoc capture asked of a process RenderDoc is not loaded in, or past the last frame
    expect_bad_input(
        &["render", "--size", "8x6", "--renderdoc-capture", "0", "--out", out.to_str().unwrap()],
        &["RenderDoc is not loaded", "renderdoccmd capture"],
    );
    expect_bad_input(
        &["render", "--size", "8x6", "--frames", "2", "--renderdoc-capture", "2", "--out", out.to_str().unwrap()],
        &["--renderdoc-capture 2 is past the last frame (1"],
    );
    expect_bad_input(
        &["reference", "--spp", "1", "--size", "8x6", "--out", d.join("r.exr").to_str().unwrap()],
        &["spp"],
    );
    // a per-vertex subdivision finer than the triangle budget (31 levels asked for the torus: once a shift
    // overflow in debug and unbounded work in release): the budget's levels, and said
    let o = penumbra(&[
        "render",
        "--technique",
        "isg-vertex",
        "--param",
        "max_edge=1e-10",
        "--size",
        "8x6",
        "--frames",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("'torus': subdivided 3 times, not the 31 times max_edge = 1e-10 asks"), "{t}");
}

/// `asset walker` writes the walking figure (that it decodes to the checked-in file is tested in
/// scene/tests/walker.rs); an unwritable path is bad input naming the file.
#[test]
fn asset_walker_writes_the_checked_in_figure() {
    let d = tmp("asset_walker");
    let out = d.join("walker.glb");
    let o = penumbra(&["asset", "walker", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("17308 vertices"), "{}", text(&o));
    // it loads: a skinned body and a hat, the vertices it reported
    let asset = penumbra_scene::gltf_load::load(&out).unwrap_or_else(|e| panic!("{e}"));
    let n: usize = asset.primitives.iter().map(|p| p.mesh.positions.len()).sum();
    assert_eq!((n, asset.animation_names.clone()), (17308, vec!["walk".to_string()]));
    let bad = d.join("no/such/dir/w.glb");
    expect_bad_input(&["asset", "walker", "--out", bad.to_str().unwrap()], &["w.glb", "cannot write"]);
}

#[test]
fn help_documents_every_command_and_flag() {
    // the registry as text: every technique with its parameters, defaults and ranges
    let o = penumbra(&["techniques"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for name in penumbra_passes::registry::names() {
        assert!(t.contains(&format!("\n{name}\n")), "{name} missing: {t}");
    }
    assert!(
        t.contains("e_max") && t.contains("default 0.10") && t.contains("volumetric") && t.contains("temporal, full"),
        "{t}"
    );
    let o = penumbra(&["--help"]);
    assert!(o.status.success());
    let t = text(&o);
    for c in ["render", "reference", "compare", "bench", "spheres"] {
        assert!(t.contains(c), "{t}");
    }
    let o = penumbra(&["render", "--help"]);
    let t = text(&o);
    for f in ["--frames", "--size", "--out", "--validate", "--dump-graph", "--profile", "graph.json", "profile.json"] {
        assert!(t.contains(f), "render --help lacks {f}: {t}");
    }
}

#[test]
fn bench_measures_techniques_against_the_reference() {
    let out = tmp("bench");
    let o = penumbra(&[
        "bench",
        "techniques",
        "--size",
        "64x48",
        "--spp",
        "16",
        "--frames",
        "2",
        "--sg-reference",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    for f in ["reference.exr", "reference_sg.exr", "env.exr", "env_diff.png", "bench.json", "tradeoff.png"] {
        assert!(out.join(f).exists(), "missing {f}");
    }
    let b: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    let env = &b["techniques"][0];
    assert_eq!(env["technique"], "env");
    assert_eq!(env["speed_ratio_vs_first"], 1.0);
    assert!(env["gpu_ms_per_frame"].as_f64().unwrap() > 0.0);
    // The unshadowed env technique agrees with ground truth up to its missing shadows: this
    // fails if the GPU and CPU renderers disagree on camera, orientation or units.
    let psnr = env["psnr_db"].as_f64().unwrap();
    assert!(psnr > 20.0, "PSNR {psnr} dB");
    let sg_psnr = env["vs_sg_reference"]["psnr_db"].as_f64().unwrap();
    assert!(sg_psnr.is_finite() && sg_psnr > 10.0, "PSNR vs the SG-lighting reference {sg_psnr} dB");
    expect_bad_input(&["bench", "techniques", "--techniques", "env,nope", "--out", out.to_str().unwrap()], &["nope"]);
    // Supersampled GPU images are box-filtered to the reference's size: a wrong pixel mapping
    // would show as a PSNR collapse against the same ground truth.
    let out2 = tmp("bench-ss");
    let o = penumbra(&[
        "bench",
        "techniques",
        "--size",
        "32x24",
        "--spp",
        "16",
        "--frames",
        "1",
        "--supersample",
        "3",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let b: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out2.join("bench.json")).unwrap()).unwrap();
    assert_eq!(b["supersample"], 3);
    let ss_psnr = b["techniques"][0]["psnr_db"].as_f64().unwrap();
    assert!(ss_psnr > 20.0, "supersampled env PSNR {ss_psnr} dB (1x at 64x48: {psnr} dB)");
    expect_bad_input(&["bench", "techniques", "--supersample", "0", "--out", out2.to_str().unwrap()], &["supersample"]);
}

#[test]
fn spheres_approximate_a_closed_mesh_and_refuse_an_open_one() {
    let d = tmp("spheres");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = d.join("bunny.spheres");
    let bunny = root.join("scenes/assets/bunny.glb");
    let o = penumbra(&["spheres", bunny.to_str().unwrap(), "--count", "16", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("16 spheres"), "{}", text(&o));
    let set = penumbra_math::sphereset::SphereSet::parse(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(set.spheres.len(), 16);
    assert!(set.spheres.iter().all(|s| s.radius > 0.0 && s.center.is_finite()));
    let scene = root.join("scenes/hat_on_cloth.toml");
    expect_bad_input(
        &["spheres", scene.to_str().unwrap(), "--object", "cloth", "--out", out.to_str().unwrap()],
        &["hat_on_cloth.toml", "cloth", "not a closed mesh"],
    );
    expect_bad_input(
        &["spheres", bunny.to_str().unwrap(), "--object", "nope", "--out", out.to_str().unwrap()],
        &["bunny.glb", "no object named 'nope'"],
    );
}

/// `bench avs` against `mc` on the brief's metric, and its pictures: the contact sheet and each
/// scene's EXRs and difference PNGs under --out.
#[test]
fn bench_avs_compares_with_mc_and_writes_its_pictures() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = root.join("scenes/balls_on_dish.toml");
    let out = tmp("bench_avs_out");
    let o = penumbra(&[
        "bench",
        "avs",
        scene.to_str().unwrap(),
        "--size",
        "24x18",
        "--no-sweep",
        "--spp",
        "4",
        "--mc-frames",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("at the pixel centres, mc aa = false") && t.contains("MC to same rmse/mean"), "{t}");
    assert!(out.join("avs_mc.png").exists(), "no contact sheet:\n{t}");
    for f in ["reference.exr", "avs.exr", "mc.exr", "avs_diff.png", "mc_diff.png"] {
        assert!(out.join("balls_on_dish").join(f).exists(), "no {f}:\n{t}");
    }
}

#[test]
fn bench_trace_and_volumetric_run_and_report() {
    let o = penumbra(&["bench", "trace", "--size", "32x24", "--incoherent", "500"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("kd-tree:") && t.contains("obvhs") && t.contains("incoherent") && t.contains("shadow (hit points"),
        "{t}"
    );
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let vol = root.join("scenes/vol_dragon.toml");
    let chart = tmp("volumetric_chart").join("vol.png");
    let o = penumbra(&[
        "bench",
        "volumetric",
        vol.to_str().unwrap(),
        "--frames",
        "3",
        "--size",
        "48x36",
        "--chart",
        chart.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("overall speedup") && t.contains("missed pixels 0") && t.contains("whole frames"), "{t}");
    assert!(chart.exists(), "no chart written:\n{t}");
    // The reuse sweep (Fig. 5.2) and the JSON report: whole-frame cost per refresh period.
    let json = tmp("volumetric_chart").join("vol.json");
    let sweep_chart = tmp("volumetric_chart").join("sweep.png");
    let o = penumbra(&[
        "bench",
        "volumetric",
        vol.to_str().unwrap(),
        "--frames",
        "4",
        "--size",
        "32x24",
        "--sweep",
        "1,4",
        "--json",
        json.to_str().unwrap(),
        "--chart",
        sweep_chart.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success() && t.contains("reuse sweep") && sweep_chart.exists(), "{t}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["reuse_frames"], 4, "the thesis's reused frame number 3 is the default");
    let sw = v["sweep"].as_array().unwrap();
    assert_eq!(sw.len(), 2);
    assert_eq!(sw[0]["reused_frame_number"], 0);
    for e in sw {
        assert!(e["frame_temporal_ms"].as_f64().unwrap() > 0.0 && e["frame_full_ms"].as_f64().unwrap() > 0.0, "{e}");
        assert_eq!(e["missed_pixels"], 0, "{e}");
    }
    // Period 1 recomputes every pixel every frame: nothing is masked.
    assert!((sw[0]["mean_marched_fraction"].as_f64().unwrap() - 1.0).abs() < 1e-9, "{}", sw[0]);
    let frames = v["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    assert!(frames.iter().all(|f| f["frame_temporal_ms"].as_f64().unwrap() >= f["vol_temporal_ms"].as_f64().unwrap()));
    let no_medium = root.join("scenes/chess.toml");
    expect_bad_input(&["bench", "volumetric", no_medium.to_str().unwrap()], &["chess.toml", "no [medium]"]);
    let d = tmp("volumetric_flag");
    let gr = root.join("scenes/god_rays.toml");
    expect_bad_input(
        &["render", gr.to_str().unwrap(), "--volumetric", "bogus", "--out", d.to_str().unwrap()],
        &["bogus"],
    );
    let o = penumbra(&[
        "render",
        gr.to_str().unwrap(),
        "--volumetric",
        "full",
        "--size",
        "48x36",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let g = std::fs::read_to_string(d.join("graph.txt")).unwrap();
    assert!(g.contains("vol_march") && !g.contains("vol_mask"), "full method has no mover mask:\n{g}");
}

#[test]
fn shadow_field_precompute_and_bench() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = root.join("scenes/sf_spheres.toml");
    let d = tmp("psf");
    let small = ["--shells", "4", "--resolution", "8", "--map-res", "8"];
    let mut args = vec!["precompute", "shadow-field", scene.to_str().unwrap(), "--out", d.to_str().unwrap()];
    args.extend(small);
    let o = penumbra(&args);
    assert!(o.status.success(), "{}", text(&o));
    let files: Vec<_> =
        std::fs::read_dir(&d).unwrap().flatten().map(|e| e.file_name().into_string().unwrap()).collect();
    assert!(
        files.iter().any(|f| f.ends_with(".adaptive.psf")) && files.iter().any(|f| f.ends_with(".fixed.psf")),
        "{files:?}"
    );
    for f in &files {
        let bytes = std::fs::read(d.join(f)).unwrap();
        penumbra_math::shadow_field::ObjectField::from_bytes(&bytes).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
    // (the image comparison against the reference renders every variant: bench-sized, skipped here)
    let mut args = vec!["bench", "shadow-fields", scene.to_str().unwrap(), "--repeats", "1", "--no-images"];
    args.extend(small);
    let o = penumbra(&args);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("per-shell R") && t.contains("GPU vs CPU") && t.contains("ms per frame"), "{t}");
    // the Figure 8 threshold sweep (statues: sf_spheres' smooth fields adapt only inside the
    // spheres, where no receiver looks): a looser threshold keeps fewer samples and differs more
    // from the fixed fields
    let statues = root.join("scenes/sf_statues.toml");
    let sweep = d.join("sweep");
    let o = penumbra(&[
        "bench",
        "shadow-fields",
        statues.to_str().unwrap(),
        "--repeats",
        "1",
        "--no-images",
        "--shells",
        "8",
        "--resolution",
        "32",
        "--map-res",
        "8",
        "--size",
        "32x24",
        "--thresholds",
        "0.05,0.002",
        "--sweep-out",
        sweep.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sweep.join("sf_thresholds.json")).unwrap()).unwrap();
    let row = |k: usize, key: &str| j["thresholds"][k][key].as_f64().unwrap_or_else(|| panic!("{key} in {j}"));
    assert!(row(0, "adaptive_bytes") < row(1, "adaptive_bytes"), "{j}");
    assert!(row(1, "adaptive_bytes") <= j["fixed_bytes"].as_f64().unwrap(), "{j}");
    assert!(row(1, "rel_rmse_vs_fixed") < row(0, "rel_rmse_vs_fixed"), "{j}");
    assert!(sweep.join("sf_thresholds.png").is_file());
    let missing = root.join("scenes/nope.toml");
    expect_bad_input(&["precompute", "shadow-field", missing.to_str().unwrap()], &["nope.toml"]);
    expect_bad_input(
        &["bench", "shadow-fields", scene.to_str().unwrap(), "--resolution", "12"],
        &["resolution", "power of two"],
    );
    expect_bad_input(
        &["bench", "shadow-fields", scene.to_str().unwrap(), "--haar", "12"],
        &["--haar 12", "power of two"],
    );
    // the paper's R = 64 with 6 x 64 x 64 cube maps: 12 GiB of raw maps per object, refused up front
    expect_bad_input(
        &["bench", "shadow-fields", scene.to_str().unwrap(), "--resolution", "64", "--haar", "64"],
        &["--haar 64", "GiB"],
    );
    expect_bad_input(&["precompute", "shadow-field", scene.to_str().unwrap(), "--shells", "0"], &["shells"]);
    // technique parameters: unknown keys and bad values
    let r = d.join("r");
    expect_bad_input(
        &[
            "render",
            scene.to_str().unwrap(),
            "--size",
            "16x12",
            "--out",
            r.to_str().unwrap(),
            "--param",
            "mode=sideways",
        ],
        &["mode", "sideways"],
    );
    expect_bad_input(
        &[
            "render",
            scene.to_str().unwrap(),
            "--size",
            "16x12",
            "--out",
            r.to_str().unwrap(),
            "--param",
            "windw=hanning",
        ],
        &["windw"],
    );
}

/// `bench soak` (short: CI; the full 1000-frame run is a README command): host RSS and device
/// memory stay flat after the warm-up for each technique on a moving scene.
#[test]
fn soak_memory_stays_flat() {
    let d = tmp("soak");
    let falling = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/falling.toml");
    let o = penumbra(&[
        "bench",
        "soak",
        falling.to_str().unwrap(),
        "--frames",
        "40",
        "--warmup",
        "12",
        "--size",
        "16x12",
        "--techniques",
        "env,mc,shadowmaps,isg,shadow-fields",
        "--out",
        d.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join("soak.json")).unwrap()).unwrap();
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 5, "{t}");
    for r in runs {
        assert_eq!(r["flat"], true, "{r}");
        let samples = r["samples"].as_array().unwrap();
        assert!(samples.len() >= 10 && samples.iter().all(|s| s["gpu_allocated_bytes"].as_u64().unwrap() > 0), "{r}");
    }
}

/// Opens `page` in headless Chromium (Debian's `chromium`, when installed): the DOM it builds
/// lists every pass, and its screenshot is not blank. Without a Chromium it says so and checks
/// nothing more (the page is static HTML and SVG, checked above as text).
fn headless_browser_shows(page: &Path, passes: &[String]) {
    let Some(browser) = ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|b| Command::new(b).arg("--version").output().is_ok_and(|o| o.status.success()))
    else {
        println!("no chromium installed: graph.html not opened in a browser");
        return;
    };
    let url = format!("file://{}", page.canonicalize().unwrap().display());
    let profile = page.with_file_name("chromium-profile");
    let common = |extra: &[String]| {
        let mut c = Command::new(browser);
        c.args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1200,900"])
            .arg(format!("--user-data-dir={}", profile.display()))
            .args(extra)
            .arg(&url);
        c.output().expect("run chromium")
    };
    let dom = common(&["--dump-dom".into()]);
    let dom_text = String::from_utf8_lossy(&dom.stdout);
    assert!(dom.status.success(), "{}", text(&dom));
    for p in passes {
        assert!(dom_text.contains(&format!("data-pass=\"{p}\"")), "the browser's DOM lacks pass {p}");
    }
    let shot = page.with_file_name("graph.png");
    let o = common(&[format!("--screenshot={}", shot.display())]);
    assert!(o.status.success() && shot.exists(), "{}", text(&o));
    let mut reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&shot).unwrap()))
        .read_info()
        .expect("screenshot PNG");
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let px = info.color_type.samples();
    let distinct: std::collections::BTreeSet<&[u8]> = buf[..info.buffer_size()].chunks_exact(px).collect();
    assert!(distinct.len() > 8, "the screenshot is blank ({} colours)", distinct.len());
    println!(
        "{browser}: graph.html shows {} passes, screenshot {}x{} with {} colours",
        passes.len(),
        info.width,
        info.height,
        distinct.len()
    );
}

/// `bench loop-guard` (issue 25) over `techniques` on two scenes that between them run every
/// family of shaders the built-in scenes run at their defaults (chess: static, so vv runs, and
/// isg-vertex over the limit, listed; god_rays: a medium and a spot light; bunny-draco, in the
/// sweep until session 27, cost as much as both) with counted loops; no invocation reaches lavapipe 22.3's limit outside the
/// checked-in known list (the guard's validation is `tests/loop_guard.rs`'s). The full sweep,
/// every built-in scene, is a README command (about 11 min here). Returns `loop_guard.json`'s shaders that ran
/// and the output.
fn loop_guard_sweep(name: &str, techniques: &[&str], tracer: &str) -> (Vec<serde_json::Value>, String) {
    let d = tmp(name);
    let scenes: Vec<String> = ["chess.toml", "god_rays.toml"]
        .iter()
        .map(|s| Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(s).to_string_lossy().into_owned())
        .collect();
    let o = penumbra(&[
        "bench",
        "loop-guard",
        "--scenes",
        &scenes.join(","),
        "--techniques",
        &techniques.join(","),
        "--size",
        "32x24",
        "--frames",
        "2",
        "--tracer",
        tracer,
        "--out",
        d.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("loop_guard.json")).unwrap()).unwrap();
    let ran = v["shaders"].as_array().unwrap().iter().filter(|s| s["cells"].as_u64().unwrap() > 0).cloned().collect();
    (ran, t)
}

/// The two halves of the sweep: isg's two modes (the slowest counted shaders) and every other
/// registered technique, so that nextest runs them side by side.
const LOOP_GUARD_ISG: &[&str] = &["isg", "isg-vertex"];

/// Every registered technique (`penumbra techniques`: the unindented names before "Effects").
fn registered_techniques() -> Vec<String> {
    let t = text(&penumbra(&["techniques"]));
    t.lines()
        .skip(1)
        .take_while(|l| !l.starts_with("Effects"))
        .filter(|l| !l.is_empty() && !l.starts_with(' ') && *l != "auto")
        .map(str::to_string)
        .collect()
}

/// The sweep's isg half (`loop_guard_sweep`), with the device-built kd-tree (`--tracer kdtree`:
/// its build's loops and its walk; the other half traces what lavapipe picks, the host-built
/// BVH). Costly: run by `scripts/test.sh` after the other tests (`--run-ignored only`), ignored
/// in plain `cargo test`.
#[test]
#[ignore = "about 2 minutes: scripts/test.sh runs it after the other tests"]
fn no_shader_reaches_the_loop_limit_unlisted_isg() {
    let (ran, t) = loop_guard_sweep("loop_guard_isg", LOOP_GUARD_ISG, "kdtree");
    for s in ["isg/isg_shade.comp", "isg/isg_vertex.comp", "isg/isg_shade_vertex.comp", "trace/kdtree_build.comp"] {
        assert!(ran.iter().any(|r| r["shader"] == s), "{s} did not run: {t}");
    }
    let isg = ran.iter().find(|s| s["shader"] == "isg/isg_shade.comp").unwrap();
    assert!(isg["max_iterations"].as_u64().unwrap() > 1000, "loops counted: {isg}");
    assert!(t.contains("known to reach the limit"), "chess's isg-vertex cell is listed: {t}");
}

/// The sweep's other half: every registered technique but isg's two modes.
#[test]
#[ignore = "about 2 minutes: scripts/test.sh runs it after the other tests"]
fn no_shader_reaches_the_loop_limit_unlisted() {
    let all = registered_techniques();
    assert!(all.len() >= 10 && LOOP_GUARD_ISG.iter().all(|t| all.iter().any(|a| a == t)), "{all:?}");
    let rest: Vec<&str> = all.iter().map(String::as_str).filter(|t| !LOOP_GUARD_ISG.contains(t)).collect();
    let (ran, t) = loop_guard_sweep("loop_guard", &rest, "auto");
    // every family of shaders ran, loops counted
    for s in [
        "avs/avs_vis.comp",
        "hsdt/hsdt.comp",
        "mc/mc.comp",
        "mc/mcd_atrous.comp",
        "shadow_fields/sf_shade.comp",
        "shadow_fields/sfw_shade.comp",
        "shadowmaps/shadowmaps_shade.comp",
        "volumetric/vol_march.frag",
        "vv/vv_shade.frag",
    ] {
        assert!(ran.iter().any(|r| r["shader"] == s), "{s} did not run: {t}");
    }
}

/// `bench hsdt --speed-only`: t_S per point, the fp16 result against the exact transform, and the
/// bytes moved against the host's and the device's bandwidth measured in the same run.
#[test]
fn hsdt_speed_only() {
    let o = penumbra(&["bench", "hsdt", "--r", "16,24", "--points", "8", "--speed-only"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(!t.contains("brute-force spherical distance"), "speed only: {t}");
    for what in ["host ", "device "] {
        let bw: f64 = t
            .split("read + write): ")
            .nth(1)
            .and_then(|s| s.split(what).nth(1))
            .and_then(|s| s.split(" GB/s").next())
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or_else(|| panic!("{what}bandwidth: {t}"));
        assert!(bw > 0.1, "{what}{bw}: {t}");
    }
    for r in ["16", "24"] {
        let rows: Vec<Vec<&str>> =
            t.lines().map(|l| l.split_whitespace().collect::<Vec<_>>()).filter(|w| w.first() == Some(&r)).collect();
        assert_eq!(rows.len(), 2, "speed and bytes rows for r = {r}: {t}");
        // speed row: r, t_S us/pt, ms/1000, CPU all, CPU one, speedup, fp16 max, fp16 mean
        let fp16_max: f64 = rows[0][6].parse().unwrap();
        assert!(rows[0][1].parse::<f64>().unwrap() > 0.0 && fp16_max < 1e-3, "{t}");
        // bytes row: r, t_S, KB per point (bits r*r/8 + fp16 2*r*r)
        let kb: f64 = rows[1][2].parse().unwrap();
        let rr: f64 = r.parse().unwrap();
        assert!((kb * 1e3 - (rr * rr / 8.0 + 2.0 * rr * rr)).abs() < 60.0, "{t}");
    }
}
