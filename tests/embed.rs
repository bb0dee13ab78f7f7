//! The embedding example, run as a test: penumbra on an application's device and image.

#[path = "../examples/embed.rs"]
mod embed;

#[test]
fn renders_into_an_application_image() {
    let mean = embed::run().expect("embedding example");
    assert!(mean > 20.0 && mean < 250.0, "target image looks empty or saturated (mean {mean})");
}
