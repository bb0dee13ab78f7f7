//! `graph.html`: one self-contained page (no network, no scripts needed to read it) that shows a
//! compiled frame to a person: the passes on a GPU timeline, every resource's lifetime over the
//! passes with its reads and writes, the barriers each pass needs, culled passes with their
//! reasons, and images the frame dumped (as thumbnails beside the pass that wrote them).
//!
//! The page is static HTML and SVG generated here; a few lines of script only add highlighting
//! (hovering a pass marks the resources it touches). Every pass is an element of class `pass`
//! with `data-pass` set to its name, which tests and tools can look for.

use crate::dump::barrier_text;
use crate::graph::compile::CompiledGraph;
use crate::graph::ResourceDesc;
use crate::profile::PassStats;
use base64::Engine as _;
use std::collections::BTreeMap;
use std::fmt::Write;

/// An image shown on the page: its name (a resource name when it is one, e.g. `gb_normal`) and
/// PNG bytes (small: it is embedded).
pub struct HtmlImage {
    pub name: String,
    pub png: Vec<u8>,
}

/// HTML text escaping (element content and attribute values).
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

fn bytes_text(b: u64) -> String {
    match b {
        b if b >= 1 << 20 => format!("{:.1} MiB", b as f64 / (1u64 << 20) as f64),
        b if b >= 1 << 10 => format!("{:.1} KiB", b as f64 / 1024.0),
        b => format!("{b} B"),
    }
}

const STYLE: &str = "body{font:13px/1.4 system-ui,sans-serif;margin:16px;color:#222;background:#fff}\
h1{font-size:18px;margin:0 0 4px}h2{font-size:15px;margin:20px 0 6px}\
.sum{color:#555}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 6px;vertical-align:top;text-align:left}\
th{background:#f2f2f2}.culled{color:#888;background:#f7f7f7}.mono{font-family:ui-monospace,monospace;font-size:12px}\
.bar{fill:#4a90d9;stroke:#fff;stroke-width:1}.bar.culled{fill:#ccc}.life{fill:#b9d4ef}.life.persist{fill:#f0c987}.life.hl,.bar.hl{fill:#e4572e}\
.w{fill:#1b5e20}.r{fill:#0d47a1}svg text{font:11px system-ui,sans-serif}img.thumb{max-width:160px;image-rendering:pixelated;border:1px solid #999;margin:2px}\
tr.pass.hl{background:#fff3e0}";

const SCRIPT: &str = "document.querySelectorAll('[data-pass]').forEach(function(e){\
var n=e.getAttribute('data-pass'),f=function(on){document.querySelectorAll('[data-pass=\"'+CSS.escape(n)+'\"],[data-users~=\"'+CSS.escape(n)+'\"]').forEach(function(x){x.classList.toggle('hl',on)})};\
e.addEventListener('mouseenter',function(){f(true)});e.addEventListener('mouseleave',function(){f(false)})});";

/// The page of compiled graph `g`: `title` heads it, `timings` (per pass name) sets the
/// timeline's widths (without them every live pass gets the same width, said on the page),
/// `images` are embedded as thumbnails.
pub fn to_html(
    g: &CompiledGraph,
    timings: Option<&BTreeMap<String, PassStats>>,
    title: &str,
    images: &[HtmlImage],
) -> String {
    let mut s = String::new();
    let live = g.live_passes().count();
    let transient: u64 = g.resources.iter().filter(|r| r.transient).map(|r| r.bytes).sum();
    let ms = |name: &str| timings.and_then(|t| t.get(name)).map(|t| t.median_ms);
    let total_ms: f64 = g.live_passes().filter_map(|(_, p)| ms(&p.name)).sum();
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body>\n\
         <h1>{t}</h1><p class=\"sum\">{} passes ({live} live, {} culled), {} resources, {} barriers, {} transient, GPU {}</p>\n",
        g.passes.len(),
        g.passes.len() - live,
        g.resources.len(),
        g.barrier_count(),
        bytes_text(transient),
        if timings.is_some() { format!("{total_ms:.3} ms (sum of the passes' medians)") } else { "not timed".into() },
        t = esc(title),
    );

    // Which pass last wrote each resource (for the thumbnails).
    let mut writer: BTreeMap<&str, usize> = BTreeMap::new();
    for (i, p) in g.live_passes() {
        for (r, _, _, wv) in &p.uses {
            if wv.is_some() {
                writer.insert(g.resources[*r as usize].name.as_str(), i);
            }
        }
    }
    let image_pass = |name: &str| writer.get(name).copied();

    // Timeline: live passes left to right, widths from the GPU medians.
    let _ = writeln!(s, "<h2>Timeline</h2>");
    if timings.is_none() {
        let _ = writeln!(
            s,
            "<p class=\"sum\">No GPU timings (render with --profile): every pass drawn the same width.</p>"
        );
    }
    let (w, row) = (1100.0f64, 26.0f64);
    let widths: Vec<(usize, f64)> =
        g.live_passes().map(|(i, p)| (i, if timings.is_some() { ms(&p.name).unwrap_or(0.0) } else { 1.0 })).collect();
    let sum: f64 = widths.iter().map(|x| x.1).sum::<f64>().max(1e-9);
    let min_w = 3.0;
    let scale = (w - min_w * widths.len() as f64).max(100.0) / sum;
    // Bars on one row; each label on the first of four lines below where it does not overlap
    // the previous label there (about 6.5 pixels per character), tied to its bar by a tick.
    let lines = 4usize;
    let mut ends = vec![f64::NEG_INFINITY; lines];
    let mut body = String::new();
    let mut x = 0.0;
    let mut used_lines = 1;
    for (i, v) in &widths {
        let p = &g.passes[*i];
        let bw = min_w + v * scale;
        let label = match ms(&p.name) {
            Some(m) => format!("{} {m:.3} ms", p.name),
            None => p.name.clone(),
        };
        let line = (0..lines)
            .find(|&l| ends[l] + 6.0 <= x)
            .unwrap_or_else(|| (0..lines).min_by(|&a, &b| ends[a].total_cmp(&ends[b])).unwrap_or(0));
        ends[line] = x + 6.5 * label.chars().count() as f64;
        used_lines = used_lines.max(line + 1);
        let ty = row + 12.0 + 15.0 * line as f64;
        let _ = writeln!(
            body,
            "<g data-pass=\"{n}\"><rect class=\"bar\" data-pass=\"{n}\" x=\"{x:.1}\" y=\"0\" width=\"{bw:.1}\" height=\"{h}\"><title>{l}</title></rect><line x1=\"{x:.1}\" y1=\"{h}\" x2=\"{x:.1}\" y2=\"{:.0}\" stroke=\"#999\"/><text x=\"{tx:.1}\" y=\"{ty}\">{l}</text></g>",
            ty - 3.0,
            n = esc(&p.name),
            h = row - 4.0,
            l = esc(&label),
            tx = x + 2.0,
        );
        x += bw;
    }
    let _ = writeln!(
        s,
        "<svg width=\"{:.0}\" height=\"{:.0}\" role=\"img\" aria-label=\"GPU timeline\">\n{body}",
        ends.iter().fold(w, |a, &e| a.max(e + 10.0)),
        row + 18.0 + 15.0 * used_lines as f64
    );
    let _ = writeln!(s, "</svg>");

    // Resource lifetimes over the pass indices.
    let n = g.passes.len().max(1) as f64;
    let (label_w, cell) = (220.0, ((w - 220.0) / n).clamp(4.0, 40.0));
    let used: Vec<_> = g.resources.iter().enumerate().filter(|(_, r)| r.first_pass.is_some()).collect();
    let _ = writeln!(s, "<h2>Resource lifetimes</h2><p class=\"sum\">Columns are passes in recording order; a bar spans a resource's first to last use (blue: transient, orange: imported or persistent); marks: <tspan>&#9650;</tspan> write, <tspan>&#9660;</tspan> read.</p>");
    // a header of pass names, slanted over their columns
    // (11 px text, about 6.5 px a character, slanted at 50 degrees: 5 px of height a character)
    let head = 16.0 + 5.0 * (g.passes.iter().map(|p| p.name.chars().count()).max().unwrap_or(4).min(60) + 4) as f64;
    let _ = writeln!(
        s,
        "<svg width=\"{:.0}\" height=\"{:.0}\" role=\"img\" aria-label=\"resource lifetimes\">",
        label_w + cell * n + 10.0 + head,
        head + 18.0 * used.len() as f64 + 10.0
    );
    for (i, p) in g.passes.iter().enumerate() {
        let cx = label_w + cell * (i as f64 + 0.5);
        let _ = writeln!(
            s,
            "<text data-pass=\"{n}\" transform=\"translate({cx:.1} {:.1}) rotate(-50)\"{}>{i} {n}</text>",
            head - 4.0,
            if p.culled.is_some() { " fill=\"#999\"" } else { "" },
            n = esc(&p.name),
        );
    }
    for (row_i, (ri, r)) in used.iter().enumerate() {
        let y = head + 18.0 * row_i as f64;
        let (a, b) = (r.first_pass.unwrap_or(0), r.last_pass.unwrap_or(0));
        let users: Vec<String> =
            g.passes.iter().filter(|p| p.uses.iter().any(|u| u.0 as usize == *ri)).map(|p| esc(&p.name)).collect();
        let _ = writeln!(
            s,
            "<g><text x=\"0\" y=\"{:.0}\">{}</text><rect class=\"life{}\" data-users=\"{}\" x=\"{:.1}\" y=\"{y:.0}\" width=\"{:.1}\" height=\"14\"><title>{} ({}, {}): passes {a}..{b}</title></rect>",
            y + 11.0,
            esc(&r.name),
            if r.transient { "" } else { " persist" },
            users.join(" "),
            label_w + cell * a as f64,
            cell * (b + 1 - a.min(b)) as f64,
            esc(&r.name),
            esc(r.origin),
            bytes_text(r.bytes),
        );
        for (pi, p) in g.passes.iter().enumerate() {
            for (u, _, rv, wv) in &p.uses {
                if *u as usize != *ri {
                    continue;
                }
                let cx = label_w + cell * (pi as f64 + 0.5);
                if wv.is_some() {
                    let _ = write!(s, "<path class=\"w\" d=\"M{:.1} {:.1}l4 6h-8z\"/>", cx, y + 1.0);
                }
                if rv.is_some() {
                    let _ = write!(s, "<path class=\"r\" d=\"M{:.1} {:.1}l4 -6h-8z\"/>", cx, y + 13.0);
                }
            }
        }
        let _ = writeln!(s, "</g>");
    }
    let _ = writeln!(s, "</svg>");

    // The passes: uses, barriers, culling, thumbnails.
    let _ = writeln!(s, "<h2>Passes</h2><table><tr><th>#</th><th>pass</th><th>GPU ms</th><th>reads / writes</th><th>barriers before it</th><th>images</th></tr>");
    for (i, p) in g.passes.iter().enumerate() {
        let culled = p.culled.as_ref();
        let mut uses = String::new();
        for (r, a, rv, wv) in &p.uses {
            let name = esc(&g.resources[*r as usize].name);
            let what = match (rv, wv) {
                (Some(v), Some(w)) => format!("rw {name} v{v}&rarr;v{w}"),
                (Some(v), None) => format!("read {name} v{v}"),
                (None, Some(w)) => format!("write {name} v{w}"),
                _ => continue,
            };
            let _ = write!(uses, "{what} <span class=\"sum\">{}</span><br>", esc(&format!("{a:?}")));
        }
        let barriers: String = p.barriers.iter().map(|b| format!("{}<br>", esc(&barrier_text(b)))).collect();
        let thumbs: String = images.iter().filter(|im| image_pass(&im.name) == Some(i)).map(thumb).collect();
        let time = match (culled, ms(&p.name)) {
            (Some(_), _) => "-".to_string(),
            (None, Some(m)) => format!("{m:.3}"),
            (None, None) => "".into(),
        };
        let _ = writeln!(
            s,
            "<tr class=\"pass{}\" id=\"pass-{i}\" data-pass=\"{n}\"><td>{i}</td><td><b>{n}</b> <span class=\"sum\">{:?}</span>{}</td><td>{time}</td><td class=\"mono\">{uses}</td><td class=\"mono\">{barriers}</td><td>{thumbs}</td></tr>",
            if culled.is_some() { " culled" } else { "" },
            p.kind,
            culled.map(|why| format!("<br><i>culled: {}</i>", esc(why))).unwrap_or_default(),
            n = esc(&p.name),
        );
    }
    let _ = writeln!(s, "</table>");
    if !g.final_barriers.is_empty() {
        let _ = writeln!(s, "<h2>Barriers after the last pass</h2><p class=\"mono\">");
        for b in &g.final_barriers {
            let _ = writeln!(s, "{}<br>", esc(&barrier_text(b)));
        }
        let _ = writeln!(s, "</p>");
    }
    // Images no pass wrote under their name (or written by a culled pass): shown together.
    let loose: Vec<&HtmlImage> = images.iter().filter(|im| image_pass(&im.name).is_none()).collect();
    if !loose.is_empty() {
        let _ = writeln!(s, "<h2>Images</h2><p>{}</p>", loose.iter().map(|im| thumb(im)).collect::<String>());
    }

    // Resources table.
    let _ = writeln!(s, "<h2>Resources</h2><table><tr><th>resource</th><th>origin</th><th>description</th><th>bytes</th><th>lifetime</th></tr>");
    for r in &g.resources {
        let d = match &r.desc {
            ResourceDesc::Image(i) => {
                format!("{:?} {}x{}, {} mips, {} layers", i.format, i.width, i.height, i.mip_levels, i.array_layers)
            }
            ResourceDesc::Buffer(b) => format!("buffer {} B", b.size),
        };
        let life = match (r.first_pass, r.last_pass) {
            (Some(a), Some(b)) => format!("{} &rarr; {}", esc(&g.passes[a].name), esc(&g.passes[b].name)),
            _ => "unused".into(),
        };
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td>{}</td><td class=\"mono\">{}</td><td>{}</td><td>{life}</td></tr>",
            esc(&r.name),
            esc(r.origin),
            esc(&d),
            bytes_text(r.bytes)
        );
    }
    let _ = writeln!(s, "</table>\n<script>{SCRIPT}</script>\n</body></html>");
    s
}

fn thumb(im: &HtmlImage) -> String {
    format!(
        "<figure style=\"display:inline-block;margin:2px\"><img class=\"thumb\" alt=\"{n}\" src=\"data:image/png;base64,{}\"><figcaption class=\"sum\">{n}</figcaption></figure>",
        base64::engine::general_purpose::STANDARD.encode(&im.png),
        n = esc(&im.name)
    )
}
