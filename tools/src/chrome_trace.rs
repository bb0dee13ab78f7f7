//! `render --trace FILE.json`: the frames' CPU spans and GPU pass intervals as a Chrome trace
//! event file (opens in Perfetto, ui.perfetto.dev, and chrome://tracing).
//!
//! Tracks: process "CPU" with thread "renderer" (building the frame graph, the technique's CPU
//! work inside it) and thread "engine" (graph compile, waiting for a frame slot, recording,
//! queue submit, fence waits); process "GPU" with one thread, the queue, whose events are the
//! passes. Vulkan gives no common clock for CPU and GPU without VK_EXT_calibrated_timestamps:
//! each frame's GPU intervals (from its timestamp queries) start when its command buffer was
//! submitted or when the previous frame's last pass ended, whichever is later (the queue runs
//! frames in order), so GPU spans are exact in length and relative position within a frame and
//! approximate in their offset to the CPU spans.

use anyhow::{Context, Result};
use penumbra::engine::FrameTimeline;
use serde_json::{json, Value};
use std::path::Path;
use std::time::Instant;

/// The trace of `frames` (frame number, timeline), in submission order.
pub fn events(frames: &[(u64, FrameTimeline)]) -> Value {
    let origin: Option<Instant> =
        frames.iter().flat_map(|(_, t)| t.cpu_spans.iter().map(|s| s.start).chain(t.submitted)).min();
    let us = |i: Instant| origin.map_or(0.0, |o| i.saturating_duration_since(o).as_secs_f64() * 1e6);
    let mut ev = vec![
        json!({"name": "process_name", "ph": "M", "pid": 1, "args": {"name": "CPU"}}),
        json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "renderer"}}),
        json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 2, "args": {"name": "engine"}}),
        json!({"name": "process_name", "ph": "M", "pid": 2, "args": {"name": "GPU"}}),
        json!({"name": "thread_name", "ph": "M", "pid": 2, "tid": 1, "args": {"name": "queue"}}),
    ];
    let mut gpu_free = 0.0f64; // where the previous frame's GPU work ended (us)
    for (frame, t) in frames {
        for s in &t.cpu_spans {
            let tid = if matches!(s.name, "build graph" | "technique") { 1 } else { 2 };
            ev.push(json!({
                "name": s.name, "cat": "cpu", "ph": "X", "pid": 1, "tid": tid,
                "ts": us(s.start), "dur": (s.ms * 1e3).max(0.0), "args": {"frame": frame},
            }));
        }
        let Some(sub) = t.submitted else { continue };
        let base = us(sub).max(gpu_free);
        for g in &t.gpu_intervals {
            let ts = base + g.start_ms * 1e3;
            ev.push(json!({
                "name": g.name, "cat": "gpu", "ph": "X", "pid": 2, "tid": 1,
                "ts": ts, "dur": (g.ms * 1e3).max(0.0), "args": {"frame": frame, "gpu_ms": g.ms},
            }));
            gpu_free = gpu_free.max(ts + g.ms * 1e3);
        }
    }
    json!({"traceEvents": ev, "displayTimeUnit": "ms"})
}

pub fn write(path: &Path, frames: &[(u64, FrameTimeline)]) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let text = serde_json::to_string(&events(frames))?;
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
