//! The embedding example, run as a test: penumbra on an application's device and image.

#[path = "../examples/embed.rs"]
mod embed;

#[test]
fn renders_into_an_application_image() {
    let mean = embed::run().expect("embedding example");
    assert!(mean > 20.0 && mean < 250.0, "target image looks empty or saturated (mean {mean})");
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
    let e = Context::from_external_with(
        ctx.entry.clone(),
        ctx.instance.clone(),
        ctx.physical,
        ctx.device.clone(),
        ctx.queue,
        ctx.queue_family,
        bad,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(
        e.contains("2 problem(s)") && e.contains("VK_KHR_push_descriptor") && e.contains("scalarBlockLayout"),
        "{e}"
    );
}
