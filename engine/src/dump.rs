//! Deterministic dumps of a compiled graph: JSON, Graphviz DOT and a readable text log.
//! No handles or addresses appear, so dumps are stable across runs and snapshot-testable.

use crate::graph::compile::{Barrier, CompiledGraph};
use crate::graph::ResourceDesc;
use crate::profile::PassStats;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::fmt::Write;

/// Vulkan flags as text; empty masks print as `NONE` rather than nothing.
fn flags<T: std::fmt::Debug>(f: T) -> String {
    let s = format!("{f:?}");
    if s.is_empty() {
        "NONE".into()
    } else {
        s
    }
}

fn barrier_json(b: &Barrier) -> Value {
    json!({
        "resource": b.name,
        "kind": if b.image { "image" } else { "buffer" },
        "reason": format!("{:?}", b.reason),
        "src_stage": flags(b.src_stage),
        "src_access": flags(b.src_access),
        "dst_stage": flags(b.dst_stage),
        "dst_access": flags(b.dst_access),
        "old_layout": if b.image { format!("{:?}", b.old_layout) } else { "-".into() },
        "new_layout": if b.image { format!("{:?}", b.new_layout) } else { "-".into() },
    })
}

fn desc_json(d: &ResourceDesc) -> Value {
    match d {
        ResourceDesc::Image(i) => json!({
            "type": "image",
            "format": format!("{:?}", i.format),
            "extent": [i.width, i.height],
            "mip_levels": i.mip_levels,
            "array_layers": i.array_layers,
        }),
        ResourceDesc::Buffer(b) => json!({ "type": "buffer", "size": b.size, "host_visible": b.host_visible }),
    }
}

/// The graph as JSON: passes (reads/writes with access kinds, culled and why, barriers),
/// resources (format, extent, bytes, lifetime, transient flag) and, if given, per-pass timings.
pub fn to_json(g: &CompiledGraph, timings: Option<&BTreeMap<String, PassStats>>) -> Value {
    let name = |r: u32| g.resources[r as usize].name.clone();
    let passes: Vec<Value> = g
        .passes
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let reads: Vec<Value> = p
                .uses
                .iter()
                .filter_map(|(r, a, rv, _)| {
                    rv.map(|v| json!({"resource": name(*r), "version": v, "access": format!("{a:?}")}))
                })
                .collect();
            let writes: Vec<Value> = p
                .uses
                .iter()
                .filter_map(|(r, a, _, wv)| {
                    wv.map(|v| json!({"resource": name(*r), "version": v, "access": format!("{a:?}")}))
                })
                .collect();
            let mut v = json!({
                "index": i,
                "name": p.name,
                "kind": format!("{:?}", p.kind),
                "culled": p.culled.is_some(),
                "side_effect": p.side_effect,
                "reads": reads,
                "writes": writes,
                "barriers": p.barriers.iter().map(barrier_json).collect::<Vec<_>>(),
            });
            if let Some(why) = &p.culled {
                v["culled_reason"] = json!(why);
            }
            if let Some(t) = timings.and_then(|t| t.get(&p.name)) {
                v["gpu_ms"] = json!({"median": t.median_ms, "min": t.min_ms, "max": t.max_ms, "frames": t.samples});
            }
            v
        })
        .collect();
    let resources: Vec<Value> = g
        .resources
        .iter()
        .map(|r| {
            json!({
                "name": r.name,
                "desc": desc_json(&r.desc),
                "origin": r.origin,
                "transient": r.transient,
                "output": r.output,
                "bytes": r.bytes,
                "lifetime": match (r.first_pass, r.last_pass) {
                    (Some(a), Some(b)) => json!([g.passes[a].name, g.passes[b].name]),
                    _ => Value::Null,
                },
                "image_usage": if r.desc.is_image() { flags(r.image_usage) } else { "-".into() },
                "buffer_usage": if r.desc.is_image() { "-".into() } else { flags(r.buffer_usage) },
            })
        })
        .collect();
    json!({
        "passes": passes,
        "resources": resources,
        "final_barriers": g.final_barriers.iter().map(barrier_json).collect::<Vec<_>>(),
        "summary": {
            "passes": g.passes.len(),
            "live_passes": g.live_passes().count(),
            "barriers": g.barrier_count(),
            "transient_bytes": g.resources.iter().filter(|r| r.transient).map(|r| r.bytes).sum::<u64>(),
        }
    })
}

fn dot_escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

/// Graphviz: passes are boxes, resource versions are ellipses, edges are reads and writes;
/// an edge into a pass that needed a barrier is labelled with the transition.
pub fn to_dot(g: &CompiledGraph) -> String {
    let mut s = String::from("digraph frame {\n  rankdir=LR;\n  node [fontname=\"monospace\", fontsize=10];\n");
    let mut versions: BTreeMap<(u32, u32), ()> = BTreeMap::new();
    for p in &g.passes {
        for (r, _, rv, wv) in &p.uses {
            for v in [rv, wv].into_iter().flatten() {
                versions.insert((*r, *v), ());
            }
        }
    }
    for (r, v) in versions.keys() {
        let res = &g.resources[*r as usize];
        let shape = if res.desc.is_image() { "ellipse" } else { "note" };
        let style = if res.transient { "" } else { ", style=bold" };
        let _ = writeln!(s, "  \"r{r}v{v}\" [label=\"{} v{v}\", shape={shape}{style}];", dot_escape(&res.name));
    }
    for (i, p) in g.passes.iter().enumerate() {
        let style =
            if p.culled.is_some() { ", style=dashed, color=gray" } else { ", style=filled, fillcolor=lightblue" };
        let _ = writeln!(s, "  \"p{i}\" [label=\"{}\", shape=box{style}];", dot_escape(&p.name));
        for (r, a, rv, wv) in &p.uses {
            let barrier = p.barriers.iter().find(|b| b.resource == *r);
            let label = match barrier {
                Some(b) if b.image => format!(
                    "{a:?}\\n{} -> {}\\n{:?} -> {:?}",
                    flags(b.src_stage),
                    flags(b.dst_stage),
                    b.old_layout,
                    b.new_layout
                ),
                Some(b) => format!("{a:?}\\n{} -> {}", flags(b.src_stage), flags(b.dst_stage)),
                None => format!("{a:?}"),
            };
            let color = if barrier.is_some() { "red" } else { "black" };
            if let Some(v) = rv {
                let _ = writeln!(
                    s,
                    "  \"r{r}v{v}\" -> \"p{i}\" [label=\"{}\", color={color}];",
                    dot_escape(&label).replace("\\\\n", "\\n")
                );
            }
            if let Some(v) = wv {
                let l = if rv.is_some() { format!("{a:?}") } else { label.clone() };
                let _ =
                    writeln!(s, "  \"p{i}\" -> \"r{r}v{v}\" [label=\"{}\"];", dot_escape(&l).replace("\\\\n", "\\n"));
            }
        }
    }
    s.push_str("}\n");
    s
}

/// A readable text log of the compiled frame.
pub fn to_text(g: &CompiledGraph, timings: Option<&BTreeMap<String, PassStats>>) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "frame graph: {} passes ({} live), {} resources, {} barriers",
        g.passes.len(),
        g.live_passes().count(),
        g.resources.len(),
        g.barrier_count()
    );
    for (i, p) in g.passes.iter().enumerate() {
        match &p.culled {
            Some(why) => {
                let _ = writeln!(s, "[{i}] {} ({:?}) CULLED: {why}", p.name, p.kind);
                continue;
            }
            None => {
                let t = timings
                    .and_then(|t| t.get(&p.name))
                    .map(|t| format!("  gpu median {:.3} ms", t.median_ms))
                    .unwrap_or_default();
                let _ = writeln!(s, "[{i}] {} ({:?}){t}", p.name, p.kind);
            }
        }
        for b in &p.barriers {
            let _ = writeln!(s, "      barrier {}", barrier_text(b));
        }
        for (r, a, rv, wv) in &p.uses {
            let n = &g.resources[*r as usize].name;
            match (rv, wv) {
                (Some(v), Some(w)) => {
                    let _ = writeln!(s, "      rw    {n} v{v}->v{w} {a:?}");
                }
                (Some(v), None) => {
                    let _ = writeln!(s, "      read  {n} v{v} {a:?}");
                }
                (None, Some(w)) => {
                    let _ = writeln!(s, "      write {n} v{w} {a:?}");
                }
                _ => {}
            }
        }
    }
    for b in &g.final_barriers {
        let _ = writeln!(s, "final barrier {}", barrier_text(b));
    }
    let _ = writeln!(s, "resources:");
    for r in &g.resources {
        let life = match (r.first_pass, r.last_pass) {
            (Some(a), Some(b)) => format!("passes {a}..{b}"),
            _ => "unused".into(),
        };
        let d = match &r.desc {
            ResourceDesc::Image(i) => format!("{:?} {}x{} mips {}", i.format, i.width, i.height, i.mip_levels),
            ResourceDesc::Buffer(b) => format!("buffer {} B", b.size),
        };
        let _ = writeln!(s, "  {} [{}] {d}, {} bytes, {life}", r.name, r.origin, r.bytes);
    }
    s
}

/// One barrier as text (resource, reason, stages and accesses, layouts).
pub(crate) fn barrier_text(b: &Barrier) -> String {
    if b.image {
        format!(
            "{} ({:?}): {}/{} -> {}/{}, {:?} -> {:?}",
            b.name,
            b.reason,
            flags(b.src_stage),
            flags(b.src_access),
            flags(b.dst_stage),
            flags(b.dst_access),
            b.old_layout,
            b.new_layout
        )
    } else {
        format!(
            "{} ({:?}): {}/{} -> {}/{}",
            b.name,
            b.reason,
            flags(b.src_stage),
            flags(b.src_access),
            flags(b.dst_stage),
            flags(b.dst_access)
        )
    }
}
