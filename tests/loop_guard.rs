//! The loop guard (issue 25): every shader compiles with its loops counted, and the counts reach
//! the host. The sweep over every scene and technique is `penumbra bench loop-guard`
//! (`tools/tests/cli.rs`, README "lavapipe's loop limit").

use penumbra::engine::{Context, ContextDesc, Engine};
use penumbra_passes::kernels::loop_probe::{run_loops, LoopCounts};

/// One invocation of `tests/loop_probe.comp` runs loops of 100 000 and 16 iterations: the guard
/// counts 100 016 iterations, one invocation past 32768 and one past 65535; a second run of two
/// short loops leaves the maximum alone and adds no invocation near the limit. The guarded
/// shader still computes what the plain one does, validation-clean.
#[test]
fn the_loop_guard_counts_every_iteration_of_an_invocation() {
    let guarded = penumbra::shader_library().with_loop_guard().expect("every shader compiles with the loop guard");
    let slot = guarded.loop_guard_slot("tests/loop_probe.comp").expect("a guarded library has slots") as usize;
    assert!(penumbra::shader_library().loop_guard_slot("tests/loop_probe.comp").is_none());

    let plain = Context::new(&ContextDesc { validation: true, ..Default::default() }).unwrap();
    let mut engine = Engine::new(plain.clone(), 1).unwrap();
    let err = run_loops(&mut engine, &guarded, 10, 10).expect_err("a guarded shader needs a guard buffer");
    assert!(format!("{err:#}").contains("loop guard"), "{err:#}");
    drop(engine);

    let ctx = Context::new(&ContextDesc { validation: true, loop_guard: true, ..Default::default() }).unwrap();
    assert!(ctx.loop_guard_address().is_some_and(|a| a != 0));
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let limit =
        penumbra_passes::kernels::loop_probe::loop_limit(&mut engine, &penumbra::shader_library(), 100_000).unwrap();
    let counts = run_loops(&mut engine, &guarded, 100_000, 16).unwrap();
    let slots = ctx.loop_guard_counts().unwrap();
    if limit.is_none() {
        assert_eq!(counts, LoopCounts { first: 100_000, second: 16 });
        assert_eq!(slots[slot], [100_016, 1, 1, 1], "max, near, at the limit, ran");
    } else {
        // a driver with the limit stops the instrumented loops too: the count stops with them
        assert!((65_535..=65_540).contains(&slots[slot][0]), "{:?} on {}", slots[slot], ctx.driver_info());
    }
    run_loops(&mut engine, &guarded, 3, 4).unwrap();
    let again = ctx.loop_guard_counts().unwrap();
    assert_eq!(again[slot], slots[slot], "short loops add nothing");
    ctx.reset_loop_guard();
    let short = run_loops(&mut engine, &guarded, 3, 4).unwrap();
    assert_eq!(short, LoopCounts { first: 3, second: 4 });
    assert_eq!(ctx.loop_guard_counts().unwrap()[slot], [7, 0, 0, 1]);
    assert!(
        ctx.loop_guard_counts().unwrap().iter().enumerate().all(|(i, s)| i == slot || *s == [0; 4]),
        "only the probe ran"
    );
    drop(engine);
    assert_eq!(ctx.validation.error_count(), 0, "{:?}", ctx.validation.errors());
}
