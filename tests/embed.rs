//! The embedding example, run as a test: penumbra on an application's device and image.

#[path = "../examples/embed.rs"]
mod embed;

/// Both modes: penumbra submitting into the application's image, and penumbra's passes
/// recorded into the application's command buffer, followed there by the application's own
/// copy of its image (whose bytes must be penumbra's frame, and the same frame as mode 1's).
#[test]
fn renders_into_an_application_image_in_both_modes() {
    let e = embed::run().expect("embedding example");
    let mean = e.submitted_mean;
    assert!(mean > 20.0 && mean < 250.0, "target image looks empty or saturated (mean {mean})");
    assert_eq!(e.host_copy.len(), e.penumbra_readback.len());
    assert!(e.host_copy == e.penumbra_readback, "the application's copy differs from penumbra's readback");
    let host_mean = e.host_copy.iter().map(|&b| b as f64).sum::<f64>() / e.host_copy.len() as f64;
    assert!((host_mean - mean).abs() < 0.5, "the recorded frame (mean {host_mean}) is not the submitted one ({mean})");
    // the Vulkan loader provides VK_EXT_debug_utils: the example enables and declares it
    assert!(e.labelled, "penumbra's passes are not labelled on the application's device");
}

/// `ctx`'s instance, device and queue wrapped as a host's would be, with `features` declared.
fn as_host(
    ctx: &penumbra::engine::Context,
    features: penumbra::engine::ExternalFeatures,
) -> anyhow::Result<std::sync::Arc<penumbra::engine::Context>> {
    let (i, d) = (ctx.instance.clone(), ctx.device.clone());
    penumbra::engine::Context::from_external_with(
        ctx.entry.clone(),
        i,
        ctx.physical,
        d,
        ctx.queue,
        ctx.queue_family,
        features,
    )
}

/// `Context::from_external_with` checks what the application declares against penumbra's needs
/// and the device, and refuses with every problem at once (issue 25).
#[test]
fn an_application_device_without_required_features_is_refused_with_every_problem() {
    use penumbra::engine::{Context, ContextDesc, ExternalFeatures};
    let ctx = Context::new(&ContextDesc::default()).expect("context");
    let ok = ExternalFeatures::default().problems(&ctx.instance, ctx.physical);
    assert!(ok.is_empty(), "{ok:?}");
    let bad = ExternalFeatures { push_descriptor: false, vulkan12: false, ..Default::default() };
    let problems = bad.problems(&ctx.instance, ctx.physical);
    assert_eq!(problems.len(), 2, "{problems:?}");
    let e = as_host(&ctx, bad).err().expect("refused").to_string();
    // a queue family that does not exist is one more problem, listed with the others
    let (i, d) = (ctx.instance.clone(), ctx.device.clone());
    let e3 = Context::from_external_with(ctx.entry.clone(), i, ctx.physical, d, ctx.queue, 99, bad)
        .err()
        .expect("refused")
        .to_string();
    assert!(e3.contains("3 problem(s)") && e3.contains("queue family 99 does not exist"), "{e3}");
    assert!(
        e.contains("2 problem(s)") && e.contains("VK_KHR_push_descriptor") && e.contains("scalarBlockLayout"),
        "{e}"
    );
    // a host that did not declare timelineSemaphore: recording into its command buffers is
    // refused by name (nothing recorded), submitting works
    let host = as_host(&ctx, ExternalFeatures::default()).expect("host context");
    let scene = penumbra_scene::Scene::default_scene();
    let settings = penumbra::RenderSettings { width: 16, height: 12, ..Default::default() };
    let mut r = penumbra::Renderer::new(host, &scene, settings).expect("renderer");
    let e = r
        .record_into(
            &scene.at(0.0, None),
            penumbra::Outputs::default(),
            true,
            penumbra::engine::vk::CommandBuffer::null(),
        )
        .err();
    let e = e.expect("refused").to_string();
    assert!(e.contains("timelineSemaphore"), "{e}");
    r.render(&scene.at(0.0, None), None, true).expect("submitting still works");
    assert_eq!(r.finish().expect("finish").len(), 1);
}

/// Frames recorded into the host's command buffer (`Renderer::record_into`) interleaved with
/// frames penumbra submits: the same images as a renderer that submits every frame (the
/// temporal history of mc-denoised and the frame-to-frame state of persistent resources carry
/// across both modes), with zero validation errors (synchronization validation on).
#[test]
fn recorded_frames_match_submitted_ones_and_are_validation_clean() {
    use penumbra::engine::vk;
    use penumbra::{RenderSettings, Renderer};
    use penumbra_scene::Scene;
    let scene = Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/falling.toml")).unwrap();
    let settings =
        || RenderSettings { width: 40, height: 30, technique: Some("mc-denoised".into()), ..Default::default() };
    let times: Vec<f32> = (0..4).map(|i| 0.5 + i as f32 / 30.0).collect();
    let mut a = Renderer::new_headless(&scene, settings(), false).expect("renderer");
    let mut want = Vec::new();
    for &t in &times {
        want.extend(a.render(&scene.at(t, None), None, true).expect("frame"));
    }
    want.extend(a.finish().expect("finish"));
    drop(a);

    let mut b = Renderer::new_headless(&scene, settings(), true).expect("renderer");
    let log = b.context().validation.clone();
    let ctx = b.context().clone();
    let d = &ctx.device;
    let pool = unsafe {
        d.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family), None)
    }
    .unwrap();
    let alloc = vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(2);
    let cmds = unsafe { d.allocate_command_buffers(&alloc) }.unwrap();
    let mut got = Vec::new();
    for (i, &t) in times.iter().enumerate() {
        let frame = scene.at(t, None);
        if i % 2 == 0 {
            got.extend(b.render(&frame, None, true).expect("frame"));
            continue;
        }
        // the host's command buffer (each used once; the previous one is done: penumbra's
        // frames in flight have been retired by then, and so has the host's submission)
        let cmd = cmds[i / 2];
        unsafe { d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()) }.unwrap();
        let rec = b.record_into(&frame, penumbra::Outputs::default(), true, cmd).expect("record");
        got.extend(rec.done);
        unsafe {
            d.end_command_buffer(cmd).unwrap();
            let infos = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
            let signals = [rec.signal.submit_info()];
            let submit = [vk::SubmitInfo2::default().command_buffer_infos(&infos).signal_semaphore_infos(&signals)];
            d.queue_submit2(ctx.queue, &submit, vk::Fence::null()).unwrap();
        }
    }
    got.extend(b.finish().expect("finish"));
    drop(b);
    unsafe { d.destroy_command_pool(pool, None) };
    assert_eq!(got.len(), times.len());
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.frame, w.frame);
        assert_eq!(g.hdr.len(), 40 * 30);
        assert!(g.hdr.iter().any(|p| p[0] > 0.0), "frame {}: black", g.frame);
        assert!(g.hdr == w.hdr, "frame {}: the recorded frame's image differs from the submitted one's", g.frame);
    }
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
}

/// A host moves its renderer to a render thread: `Renderer` is `Send` (every technique and
/// effect is), and the shared `Context` is `Send + Sync`. Checked at compile time, used here.
#[test]
fn a_renderer_moves_to_another_thread() {
    fn send<T: Send>() {}
    fn send_sync<T: Send + Sync>() {}
    send::<penumbra::Renderer>();
    send_sync::<penumbra::engine::Context>();
    let scene = penumbra_scene::Scene::default_scene();
    let settings = penumbra::RenderSettings { width: 16, height: 12, ..Default::default() };
    let mut r = penumbra::Renderer::new_headless(&scene, settings, false).expect("renderer");
    let frames = std::thread::spawn(move || {
        let mut v = r.render(&scene.at(0.0, None), None, true).expect("frame");
        v.extend(r.finish().expect("finish"));
        v
    })
    .join()
    .expect("render thread");
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].ldr.len(), 16 * 12 * 4);
}

/// Debug labels and object names reach a capture tool when embedded too: a host that enabled
/// `VK_EXT_debug_utils` on its instance says so (`ExternalFeatures::debug_utils`) and penumbra
/// names its objects and labels its passes (without the claim it cannot know, and does not).
#[test]
fn embedded_debug_labels_follow_the_hosts_instance() {
    use penumbra::engine::{Context, ContextDesc, ExternalFeatures};
    let ctx = Context::new(&ContextDesc::default()).expect("context");
    assert!(ctx.debug_utils.is_some(), "penumbra's own instance enables VK_EXT_debug_utils where the loader has it");
    let wrap = |debug_utils| as_host(&ctx, ExternalFeatures { debug_utils, ..Default::default() });
    assert!(wrap(false).expect("host context").debug_utils.is_none());
    let host = wrap(true).expect("an instance with debug utils");
    assert!(host.debug_utils.is_some());
    // its passes are labelled in the command buffers it records (a frame runs through it)
    let scene = penumbra_scene::Scene::default_scene();
    let settings = penumbra::RenderSettings { width: 16, height: 12, ..Default::default() };
    let mut r = penumbra::Renderer::new(host, &scene, settings).expect("renderer");
    r.render(&scene.at(0.0, None), None, true).expect("frame");
    assert_eq!(r.finish().expect("finish").len(), 1);
}

/// HDR and depth outputs: a host's float image and depth image receive the frame's linear
/// radiance and G-buffer depth (compared texel for texel with penumbra's own readbacks);
/// images of the wrong size or format are refused by name.
#[test]
fn hdr_and_depth_outputs_are_the_frames() {
    use penumbra::engine::{vk, Access, Graph, ImageDesc, ImportedImage, SubmitSync};
    use penumbra::{decode_texels, Outputs, RenderSettings, Renderer};
    let scene = penumbra_scene::Scene::default_scene();
    let (w, h) = (48, 32);
    let settings = RenderSettings { width: w, height: h, dump_passes: true, ..Default::default() };
    let mut r = Renderer::new_headless(&scene, settings, true).expect("renderer");
    let ctx = r.context().clone();
    let usage = vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC;
    let make = |name: &str, format| ctx.create_image(name, &ImageDesc::new_2d(format, w, h), usage).expect("image");
    let hdr_img = make("host_hdr", vk::Format::R32G32B32A32_SFLOAT);
    let depth_img = make("host_depth", vk::Format::D32_SFLOAT);
    let import =
        |img: &penumbra::engine::GpuImage, initial: Option<Access>, layout, last: Option<Access>| ImportedImage {
            image: img.image,
            view: img.view,
            desc: img.desc.clone(),
            usage,
            initial,
            initial_layout: layout,
            final_access: last,
        };
    let fresh = |img| import(img, None, vk::ImageLayout::UNDEFINED, Some(Access::TransferSrc));
    let outputs = Outputs { ldr: None, hdr: Some(fresh(&hdr_img)), depth: Some(fresh(&depth_img)) };
    let mut frames = r.render_outputs(&scene.at(0.0, None), outputs, true, &SubmitSync::default()).expect("frame");
    frames.extend(r.finish().expect("finish"));
    let f = frames.pop().expect("the frame");
    // the host reads its images back (a graph of its own on penumbra's engine)
    let mut g = Graph::new();
    let after = |img| import(img, Some(Access::TransferSrc), vk::ImageLayout::TRANSFER_SRC_OPTIMAL, None);
    let (hh, dh) =
        (g.import_image("host_hdr_image", after(&hdr_img)), g.import_image("host_depth_image", after(&depth_img)));
    penumbra_passes::readback::add(&mut g, "host_readback", &[(hh, "host_hdr"), (dh, "host_depth")]);
    let out = r.engine.submit_wait(g).expect("host readback");
    let host_hdr = decode_texels(vk::Format::R32G32B32A32_SFLOAT, &out.readbacks["host_hdr"]).unwrap();
    let host_depth = decode_texels(vk::Format::D32_SFLOAT, &out.readbacks["host_depth"]).unwrap();
    assert_eq!(host_hdr.len(), (w * h) as usize);
    assert!(host_hdr == f.hdr, "the host's HDR image is not the frame's radiance");
    let depth = &f.dumps.iter().find(|(n, _)| n == "gb_depth").expect("the G-buffer depth dump").1;
    assert!(&host_depth == depth, "the host's depth image is not the frame's depth");
    assert!(depth.iter().any(|d| d[0] < 1.0) && depth.iter().any(|d| d[0] == 1.0), "geometry and background");
    // wrong size, wrong depth format: refused naming the output
    let small = ctx.create_image("small", &ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, 8, 8), usage).unwrap();
    let bad = Outputs { hdr: Some(fresh(&small)), ..Default::default() };
    let e = r.render_outputs(&scene.at(0.0, None), bad, false, &SubmitSync::default()).expect_err("refused");
    assert!(e.to_string().contains("the HDR output is 8x8") && e.to_string().contains("48x32"), "{e}");
    let bad = Outputs { depth: Some(fresh(&hdr_img)), ..Default::default() };
    let e = r.render_outputs(&scene.at(0.0, None), bad, false, &SubmitSync::default()).expect_err("refused");
    assert!(e.to_string().contains("the depth output") && e.to_string().contains("D32_SFLOAT"), "{e}");
    let log = ctx.validation.clone();
    drop(r);
    for img in [hdr_img, depth_img, small] {
        ctx.destroy_image(img);
    }
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
}
