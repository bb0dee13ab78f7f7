//! Graph tests that need no GPU: barriers, culling, validation, dumps.

use super::compile::BarrierReason;
use super::*;
use crate::dump;
use ash::vk::{AccessFlags2 as A, ImageLayout as L, PipelineStageFlags2 as S};

fn color(g: &mut Graph, name: &str) -> ImageHandle {
    g.create_image(name, ImageDesc::new_2d(vk::Format::R16G16B16A16_SFLOAT, 64, 32))
}

fn target(g: &mut Graph) -> ImageHandle {
    g.import_image(
        "target",
        ImportedImage {
            image: vk::Image::null(),
            view: vk::ImageView::null(),
            desc: ImageDesc::new_2d(vk::Format::R8G8B8A8_UNORM, 64, 32),
            usage: vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_SRC,
            initial: None,
            initial_layout: vk::ImageLayout::UNDEFINED,
            final_access: Some(Access::TransferSrc),
        },
    )
}

/// raster gbuffer -> compute shade -> compute tonemap into an imported target.
fn small_frame() -> Graph {
    let mut g = Graph::new();
    let depth = g.create_image("depth", ImageDesc::new_2d(vk::Format::D32_SFLOAT, 64, 32));
    let albedo = color(&mut g, "albedo");
    let hdr = color(&mut g, "hdr");
    let out = target(&mut g);
    let unused = color(&mut g, "debug_view");

    let mut p = g.pass("gbuffer", PassKind::Raster);
    let _depth = p.write(depth, Access::DepthAttachmentWrite);
    let albedo = p.write(albedo, Access::ColorAttachmentWrite);
    p.finish();

    let mut p = g.pass("shade", PassKind::Compute);
    p.read(albedo, Access::ComputeShaderReadSampled);
    let hdr = p.write(hdr, Access::ComputeShaderWriteStorage);
    p.finish();

    let mut p = g.pass("debug", PassKind::Compute);
    p.read(albedo, Access::ComputeShaderReadSampled);
    p.write(unused, Access::ComputeShaderWriteStorage);
    p.finish();

    let mut p = g.pass("tonemap", PassKind::Compute);
    p.read(hdr, Access::ComputeShaderReadSampled);
    p.read(albedo, Access::ComputeShaderReadSampled);
    p.write(out, Access::ComputeShaderWriteStorage);
    p.finish();
    g
}

#[test]
fn barriers_follow_declarations() {
    let c = small_frame().compile().expect("valid graph");
    let gb = c.pass("gbuffer").unwrap();
    assert_eq!(gb.barriers.len(), 2, "first use of depth and albedo: layout transitions from UNDEFINED");
    for b in &gb.barriers {
        assert_eq!(b.old_layout, L::UNDEFINED);
        assert_eq!(b.src_stage, S::NONE);
        assert_eq!(b.reason, BarrierReason::Layout);
    }
    let shade = c.pass("shade").unwrap();
    let alb = shade.barriers.iter().find(|b| b.name == "albedo").unwrap();
    assert_eq!(alb.src_stage, S::COLOR_ATTACHMENT_OUTPUT);
    assert_eq!(alb.src_access, A::COLOR_ATTACHMENT_WRITE | A::COLOR_ATTACHMENT_READ);
    assert_eq!(alb.dst_stage, S::COMPUTE_SHADER);
    assert_eq!(alb.dst_access, A::SHADER_SAMPLED_READ);
    assert_eq!((alb.old_layout, alb.new_layout), (L::COLOR_ATTACHMENT_OPTIMAL, L::SHADER_READ_ONLY_OPTIMAL));
    let hdr = shade.barriers.iter().find(|b| b.name == "hdr").unwrap();
    assert_eq!((hdr.old_layout, hdr.new_layout), (L::UNDEFINED, L::GENERAL));

    let tm = c.pass("tonemap").unwrap();
    // albedo was already made visible to compute sampled reads: no second barrier.
    assert!(tm.barriers.iter().all(|b| b.name != "albedo"), "redundant read-after-read barrier emitted");
    let h = tm.barriers.iter().find(|b| b.name == "hdr").unwrap();
    assert_eq!((h.src_stage, h.src_access), (S::COMPUTE_SHADER, A::SHADER_STORAGE_WRITE));
    assert_eq!((h.old_layout, h.new_layout), (L::GENERAL, L::SHADER_READ_ONLY_OPTIMAL));
    // The imported target ends in TransferSrc.
    assert_eq!(c.final_barriers.len(), 1);
    let f = &c.final_barriers[0];
    assert_eq!((f.old_layout, f.new_layout), (L::GENERAL, L::TRANSFER_SRC_OPTIMAL));
    assert_eq!((f.src_access, f.dst_access), (A::SHADER_STORAGE_WRITE, A::TRANSFER_READ));
}

#[test]
fn culls_passes_that_reach_no_output() {
    let c = small_frame().compile().unwrap();
    let debug = c.pass("debug").unwrap();
    let why = debug.culled.as_deref().expect("debug pass must be culled");
    assert!(why.contains("debug_view"), "{why}");
    assert!(c.pass("tonemap").unwrap().culled.is_none());
    assert!(c.pass("gbuffer").unwrap().culled.is_none());
    assert_eq!(c.live_passes().count(), 3);
    // A culled pass contributes no barriers and no lifetime.
    let dv = c.resources.iter().find(|r| r.name == "debug_view").unwrap();
    assert!(dv.first_pass.is_none());
}

#[test]
fn side_effect_pass_is_kept_and_dead_chain_is_culled() {
    let mut g = Graph::new();
    let a = color(&mut g, "a");
    let b = color(&mut g, "b");
    let mut p = g.pass("make_a", PassKind::Compute);
    let a = p.write(a, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("a_to_b", PassKind::Compute);
    p.read(a, Access::ComputeShaderReadSampled);
    p.write(b, Access::ComputeShaderWriteStorage);
    p.finish();
    let c = g.compile().unwrap();
    assert!(c.passes.iter().all(|p| p.culled.is_some()), "nothing reaches an output");

    let mut g = Graph::new();
    let a = color(&mut g, "a");
    let mut p = g.pass("make_a", PassKind::Compute);
    let a = p.write(a, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("print", PassKind::Compute);
    p.read(a, Access::ComputeShaderReadStorage);
    p.side_effect();
    p.finish();
    let c = g.compile().unwrap();
    assert_eq!(c.live_passes().count(), 2);
}

#[test]
fn read_write_chains_and_war() {
    let mut g = Graph::new();
    let buf = g.create_buffer("counts", 1024);
    let rb = g.create_readback("counts_rb", 1024);
    let mut p = g.pass("clear", PassKind::Transfer);
    let buf = p.write(buf, Access::TransferDst);
    p.finish();
    let mut p = g.pass("accumulate", PassKind::Compute);
    let buf2 = p.write(buf, Access::ComputeShaderReadWriteStorage);
    p.finish();
    let mut p = g.pass("copy_out", PassKind::Transfer);
    p.read(buf2, Access::TransferSrc);
    p.write(rb, Access::TransferDst);
    p.finish();
    let mut p = g.pass("overwrite", PassKind::Compute);
    let buf3 = p.write(buf2, Access::ComputeShaderWriteStorage);
    p.finish();
    g.mark_output(buf3);
    let c = g.compile().unwrap();
    assert_eq!(c.live_passes().count(), 4);
    let acc = &c.pass("accumulate").unwrap().barriers[0];
    assert_eq!(acc.reason, BarrierReason::WriteAfterWrite);
    assert_eq!((acc.src_stage, acc.src_access), (S::COPY | S::BLIT | S::CLEAR, A::TRANSFER_WRITE));
    assert_eq!(acc.dst_access, A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE);
    let ow = &c.pass("overwrite").unwrap().barriers[0];
    assert_eq!(ow.reason, BarrierReason::WriteAfterRead);
    assert!(ow.src_stage.contains(S::COPY), "must wait for the copy that reads it");
    // Readback ends with a host-read barrier.
    let f = c.final_barriers.iter().find(|b| b.name == "counts_rb").unwrap();
    assert_eq!((f.dst_stage, f.dst_access), (S::HOST, A::HOST_READ));
}

#[test]
fn validation_reports_every_problem_together() {
    let mut g = Graph::new();
    let never_written = color(&mut g, "never_written");
    let buf = g.create_buffer("buf", 64);
    let depth_as_color = g.create_image("depth", ImageDesc::new_2d(vk::Format::D32_SFLOAT, 8, 8));
    let t = target(&mut g);
    let mut p = g.pass("bad", PassKind::Compute);
    p.read(never_written, Access::ComputeShaderReadSampled);
    p.write(buf, Access::ColorAttachmentWrite); // image-only access on a buffer (and not a compute access)
    p.write(depth_as_color, Access::ComputeShaderWriteStorage); // storage write on a depth format
    p.read(t, Access::ComputeShaderReadSampled); // imported without SAMPLED usage
    p.finish();
    let err = g.compile().expect_err("must fail");
    let text = err.to_string();
    let kinds: Vec<_> = err.problems.iter().map(std::mem::discriminant).collect();
    assert!(err.problems.len() >= 5, "{text}");
    assert!(
        err.problems
            .iter()
            .any(|p| matches!(p, Problem::ReadBeforeWrite { resource, .. } if resource == "never_written")),
        "{text}"
    );
    assert!(
        err.problems.iter().any(|p| matches!(p, Problem::AccessKind { resource, .. } if resource == "buf")),
        "{text}"
    );
    assert!(
        err.problems.iter().any(|p| matches!(p, Problem::Format { resource, .. } if resource == "depth")),
        "{text}"
    );
    assert!(
        err.problems.iter().any(|p| matches!(p, Problem::MissingUsage { resource, .. } if resource == "target")),
        "{text}"
    );
    assert!(err.problems.iter().any(|p| matches!(p, Problem::PassKind { .. })), "{text}");
    assert!(kinds.len() == err.problems.len());
    assert!(text.contains("pass 'bad'"), "{text}");
}

#[test]
fn stale_versions_are_rejected() {
    let mut g = Graph::new();
    let a0 = color(&mut g, "a");
    let mut p = g.pass("w1", PassKind::Compute);
    let a1 = p.write(a0, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("w2", PassKind::Compute);
    let a2 = p.write(a1, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("reads_old", PassKind::Compute);
    p.read(a1, Access::ComputeShaderReadSampled);
    p.side_effect();
    p.finish();
    let mut p = g.pass("writes_old", PassKind::Compute);
    p.write(a1, Access::ComputeShaderWriteStorage);
    p.finish();
    g.mark_output(a2);
    let err = g.compile().unwrap_err();
    assert!(
        err.problems
            .iter()
            .any(|p| matches!(p, Problem::StaleRead { pass, version: 1, latest: 2, .. } if pass == "reads_old")),
        "{err}"
    );
    assert!(
        err.problems.iter().any(|p| matches!(p, Problem::StaleWrite { pass, .. } if pass == "writes_old")),
        "{err}"
    );
}

#[test]
fn wrong_read_write_declarations_are_caught() {
    let mut g = Graph::new();
    let a = color(&mut g, "a");
    let mut p = g.pass("p", PassKind::Compute);
    let a = p.read(a, Access::ComputeShaderWriteStorage);
    p.write(a, Access::ComputeShaderReadSampled);
    p.finish();
    let err = g.compile().unwrap_err();
    assert!(err.problems.iter().any(|p| matches!(p, Problem::WriteDeclaredAsRead { .. })), "{err}");
    assert!(err.problems.iter().any(|p| matches!(p, Problem::ReadDeclaredAsWrite { .. })), "{err}");
}

#[test]
fn conflicting_layouts_in_one_pass() {
    let mut g = Graph::new();
    let a = color(&mut g, "a");
    let mut p = g.pass("w", PassKind::Compute);
    let a = p.write(a, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("both", PassKind::Compute);
    p.read(a, Access::ComputeShaderReadSampled);
    p.read(a, Access::ComputeShaderReadStorage);
    p.side_effect();
    p.finish();
    let err = g.compile().unwrap_err();
    assert!(matches!(&err.problems[0], Problem::ConflictingLayouts { resource, .. } if resource == "a"), "{err}");
}

#[test]
fn persistent_state_carries_over() {
    // Frame 1 writes a history image; frame 2 reads it: the barrier waits on frame 1's write.
    let mut g = Graph::new();
    let h = g.persistent_image("history", ImageDesc::new_2d(vk::Format::R16G16B16A16_SFLOAT, 8, 8), None);
    assert!(g.persistent_is_new(h));
    let mut p = g.pass("write_history", PassKind::Compute);
    p.write(h, Access::ComputeShaderWriteStorage);
    p.finish();
    let c1 = g.compile().unwrap();
    assert_eq!(c1.live_passes().count(), 1, "a persistent write is an output");
    let state = c1.resources[0].final_state.clone();
    assert_eq!(state.layout, L::GENERAL);

    let mut g = Graph::new();
    let h = g.persistent_image("history", ImageDesc::new_2d(vk::Format::R16G16B16A16_SFLOAT, 8, 8), Some(state));
    assert!(!g.persistent_is_new(h));
    let mut p = g.pass("read_history", PassKind::Compute);
    p.read(h, Access::ComputeShaderReadSampled);
    p.side_effect();
    p.finish();
    let c2 = g.compile().unwrap();
    let b = &c2.passes[0].barriers[0];
    assert_eq!((b.src_stage, b.src_access), (S::COMPUTE_SHADER, A::SHADER_STORAGE_WRITE));
    assert_eq!((b.old_layout, b.new_layout), (L::GENERAL, L::SHADER_READ_ONLY_OPTIMAL));
}

#[test]
fn reads_in_different_stages_each_get_visibility() {
    let mut g = Graph::new();
    let a = color(&mut g, "a");
    let mut p = g.pass("w", PassKind::Compute);
    let a = p.write(a, Access::ComputeShaderWriteStorage);
    p.finish();
    let mut p = g.pass("frag", PassKind::Raster);
    p.read(a, Access::FragmentShaderReadSampled);
    p.side_effect();
    p.finish();
    let mut p = g.pass("comp", PassKind::Compute);
    p.read(a, Access::ComputeShaderReadSampled);
    p.side_effect();
    p.finish();
    let c = g.compile().unwrap();
    assert_eq!(c.pass("frag").unwrap().barriers.len(), 1);
    let b = &c.pass("comp").unwrap().barriers;
    assert_eq!(b.len(), 1, "compute reads were not covered by the fragment barrier");
    assert_eq!(b[0].reason, BarrierReason::ReadAfterWrite);
    assert!(b[0].src_stage.contains(S::COMPUTE_SHADER));
}

#[test]
fn dumps_are_deterministic_and_match_snapshot() {
    let c = small_frame().compile().unwrap();
    let text = dump::to_text(&c, None);
    let json = serde_json::to_string_pretty(&dump::to_json(&c, None)).unwrap();
    let dot = dump::to_dot(&c);
    let c2 = small_frame().compile().unwrap();
    assert_eq!(text, dump::to_text(&c2, None));
    assert_eq!(json, serde_json::to_string_pretty(&dump::to_json(&c2, None)).unwrap());
    assert_eq!(dot, dump::to_dot(&c2));
    assert!(dot.starts_with("digraph frame {") && dot.trim_end().ends_with('}'));
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots");
    for (name, got) in [("small_frame.txt", &text), ("small_frame.json", &json), ("small_frame.dot", &dot)] {
        let path = dir.join(name);
        if std::env::var_os("UPDATE_SNAPSHOTS").is_some() {
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(&path, got).unwrap();
        }
        let want = std::fs::read_to_string(&path)
            .unwrap_or_else(|_| panic!("missing snapshot {} (run with UPDATE_SNAPSHOTS=1)", path.display()));
        assert_eq!(got, &want, "snapshot {name} differs (rerun with UPDATE_SNAPSHOTS=1 if intended)");
    }
}

/// graph.html: every pass is a row (culled ones with their reason), every used resource a
/// lifetime bar, names are escaped, images are embedded beside their writer, nothing is fetched.
#[test]
fn html_page_lists_passes_lifetimes_barriers_and_images() {
    use crate::dump_html::{to_html, HtmlImage};
    let mut g = small_frame();
    // a name that needs escaping
    let x = color(&mut g, "a<b>&\"c\"");
    let mut p = g.pass("odd <pass>", PassKind::Compute);
    p.write(x, Access::ComputeShaderWriteStorage);
    p.side_effect();
    p.finish();
    let c = g.compile().unwrap();
    let mut timings = std::collections::BTreeMap::new();
    timings.insert(
        "shade".to_string(),
        crate::profile::PassStats { median_ms: 2.5, min_ms: 2.0, max_ms: 3.0, samples: 4 },
    );
    let png = vec![0x89, b'P', b'N', b'G'];
    let images = [HtmlImage { name: "hdr".into(), png: png.clone() }, HtmlImage { name: "elsewhere".into(), png }];
    let html = to_html(&c, Some(&timings), "small <frame>", &images);
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    for (i, p) in c.passes.iter().enumerate() {
        let row = format!("id=\"pass-{i}\"");
        assert!(html.contains(&row), "no row for {}", p.name);
    }
    assert_eq!(html.matches("<tr class=\"pass").count(), c.passes.len());
    assert!(html.contains("<tr class=\"pass culled\" id=\"pass-2\" data-pass=\"debug\">"), "{html}");
    assert!(html.contains("culled: "), "the culled pass's reason");
    assert!(html.contains("odd &lt;pass&gt;") && !html.contains("odd <pass>"));
    assert!(html.contains("a&lt;b&gt;&amp;&quot;c&quot;"));
    assert!(html.contains("<title>small &lt;frame&gt;</title>"));
    assert!(html.contains("shade 2.500 ms"), "timeline label with the median");
    // one lifetime bar per used resource
    let used = c.resources.iter().filter(|r| r.first_pass.is_some()).count();
    assert_eq!(html.matches("<rect class=\"life").count(), used);
    // barriers: the gbuffer's layout transitions are listed in its row
    let gb_row = &html[html.find("id=\"pass-0\"").unwrap()..html.find("id=\"pass-1\"").unwrap()];
    assert_eq!(gb_row.matches("UNDEFINED").count(), 2, "{gb_row}");
    // the hdr image sits in the row of the pass that wrote it (shade); the other one below
    let shade_row = &html[html.find("id=\"pass-1\"").unwrap()..html.find("id=\"pass-2\"").unwrap()];
    assert!(shade_row.contains("data:image/png;base64,iVBORw"), "{shade_row}");
    assert!(html.contains("<h2>Images</h2>") && html.contains("alt=\"elsewhere\""));
    // self-contained
    assert!(!html.contains("http://") && !html.contains("https://"));
    // without timings: said, and still every live pass on the timeline
    let html = to_html(&c, None, "t", &[]);
    assert!(html.contains("No GPU timings"));
    assert_eq!(html.matches("<rect class=\"bar\"").count(), c.live_passes().count());
}

#[test]
fn depth_stencil_formats_need_depth_stencil_accesses() {
    let mut g = Graph::new();
    let ds = g.create_image("mask", ImageDesc::new_2d(vk::Format::D32_SFLOAT_S8_UINT, 8, 8));
    let d = g.create_image("depth", ImageDesc::new_2d(vk::Format::D32_SFLOAT, 8, 8));
    let mut p = g.pass("wrong", PassKind::Raster);
    p.write(ds, Access::DepthAttachmentWrite); // stencil aspect in a depth-only layout
    p.write(d, Access::DepthStencilAttachmentWrite); // no stencil aspect
    p.side_effect();
    p.finish();
    let err = g.compile().unwrap_err();
    assert!(err.problems.iter().any(|p| matches!(p, Problem::Format { resource, .. } if resource == "mask")), "{err}");
    assert!(err.problems.iter().any(|p| matches!(p, Problem::Format { resource, .. } if resource == "depth")), "{err}");

    let mut g = Graph::new();
    let ds = g.create_image("mask", ImageDesc::new_2d(vk::Format::D32_SFLOAT_S8_UINT, 8, 8));
    let mut p = g.pass("stencil", PassKind::Raster);
    let ds = p.write(ds, Access::DepthStencilAttachmentWrite);
    p.finish();
    let mut p = g.pass("test", PassKind::Raster);
    p.read(ds, Access::DepthStencilAttachmentRead);
    p.side_effect();
    p.finish();
    let c = g.compile().unwrap();
    let b = &c.pass("test").unwrap().barriers[0];
    assert_eq!((b.old_layout, b.new_layout), (L::DEPTH_STENCIL_ATTACHMENT_OPTIMAL, L::DEPTH_STENCIL_READ_ONLY_OPTIMAL));
    assert_eq!(b.src_access, A::DEPTH_STENCIL_ATTACHMENT_READ | A::DEPTH_STENCIL_ATTACHMENT_WRITE);
}

/// A swapchain image: blitted into, then presented. After its first present the image starts
/// in `Present` (PRESENT_SRC layout, execution dependency on the acquire semaphore waited at
/// ALL_COMMANDS); it ends in `Present`; no pass may declare `Present`.
#[test]
fn swapchain_image_barriers_chain_with_the_semaphores() {
    let build = |initial: Option<Access>, bad_pass: bool| {
        let mut g = Graph::new();
        let src = g.create_image("ldr", ImageDesc::new_2d(vk::Format::R8G8B8A8_UNORM, 64, 32));
        let sc = g.import_image(
            "swapchain",
            ImportedImage {
                image: vk::Image::null(),
                view: vk::ImageView::null(),
                desc: ImageDesc::new_2d(vk::Format::B8G8R8A8_UNORM, 80, 40),
                usage: vk::ImageUsageFlags::TRANSFER_DST,
                initial,
                initial_layout: vk::ImageLayout::UNDEFINED,
                final_access: Some(Access::Present),
            },
        );
        let mut p = g.pass("tonemap", PassKind::Compute);
        let src = p.write(src, Access::ComputeShaderWriteStorage);
        p.record(|_| Ok(()));
        let mut p = g.pass("blit", PassKind::Transfer);
        p.read(src, Access::TransferSrc);
        let sc = p.write(sc, Access::TransferDst);
        p.record(|_| Ok(()));
        if bad_pass {
            let mut p = g.pass("present_in_a_pass", PassKind::Transfer);
            p.read(sc, Access::Present);
            p.record(|_| Ok(()));
        }
        g.compile()
    };
    // First use: contents undefined.
    let c = build(None, false).expect("valid graph");
    let b = c.pass("blit").unwrap();
    let s = b.barriers.iter().find(|b| b.name == "swapchain").unwrap();
    assert_eq!((s.old_layout, s.new_layout), (L::UNDEFINED, L::TRANSFER_DST_OPTIMAL));
    let l = b.barriers.iter().find(|b| b.name == "ldr").unwrap();
    assert_eq!((l.src_stage, l.dst_stage), (S::COMPUTE_SHADER, S::COPY | S::BLIT));
    // Presented before: wait for the acquire semaphore's stage, from PRESENT_SRC.
    let c = build(Some(Access::Present), false).expect("valid graph");
    let s = c.pass("blit").unwrap().barriers.iter().find(|b| b.name == "swapchain").unwrap().clone();
    assert_eq!((s.old_layout, s.new_layout), (L::PRESENT_SRC_KHR, L::TRANSFER_DST_OPTIMAL));
    assert_eq!(s.src_stage, S::ALL_COMMANDS);
    assert_eq!(s.dst_stage, S::COPY | S::BLIT | S::CLEAR);
    assert_eq!(c.final_barriers.len(), 1);
    let f = &c.final_barriers[0];
    assert_eq!((f.old_layout, f.new_layout), (L::TRANSFER_DST_OPTIMAL, L::PRESENT_SRC_KHR));
    assert_eq!((f.src_stage, f.src_access), (S::COPY | S::BLIT | S::CLEAR, A::TRANSFER_WRITE));
    assert_eq!((f.dst_stage, f.dst_access), (S::ALL_COMMANDS, A::NONE));
    let err = build(Some(Access::Present), true).expect_err("Present in a pass");
    assert!(err.to_string().contains("pass 'present_in_a_pass' declares Present"), "{err}");
}
