//! PNG charts of the benches' trade-offs (error against time, quality against a parameter),
//! drawn with plotters' bitmap backend and a bundled font (DejaVu Sans Mono, licence in
//! `tools/assets/DejaVuSansMono.LICENSE`), so no system font library is needed.

use anyhow::{anyhow, bail, Context as _, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;
use std::sync::Once;

const FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");
pub(crate) const FAMILY: &str = "penumbra-mono";

/// One line of points (drawn in the given order) with a legend entry; `labels`, when not empty,
/// annotates each point (e.g. the parameter value it was measured at).
#[derive(Clone, Debug, Default)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub labels: Vec<String>,
}

/// Axis titles and scales of a chart.
#[derive(Clone, Debug)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Logarithmic x axis (points with x <= 0 are left out); linear when the points span less
    /// than a decade (a log axis would have no tick label).
    pub log_x: bool,
    /// Logarithmic y axis (points with y <= 0 are left out); linear within a decade, as x.
    pub log_y: bool,
    /// Draw a legend box of the series' names (leave it off when every point is labelled).
    pub legend: bool,
}

impl Chart {
    /// Linear axes with a legend; see [`Chart::log`] and [`Chart::legend`].
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        let (title, x_label, y_label) = (title.into(), x_label.into(), y_label.into());
        Chart { title, x_label, y_label, log_x: false, log_y: false, legend: true }
    }

    /// Logarithmic x and/or y axes.
    pub fn log(self, log_x: bool, log_y: bool) -> Self {
        Chart { log_x, log_y, ..self }
    }

    /// With or without a legend box.
    pub fn legend(self, legend: bool) -> Self {
        Chart { legend, ..self }
    }
}

pub(crate) fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut res = Ok(());
    ONCE.call_once(|| {
        res = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
            .map_err(|_| anyhow!("the bundled chart font does not parse"));
    });
    res
}

/// The padded range of `v` (a single value gets a unit-wide range).
fn range(v: impl Iterator<Item = f64>, log: bool) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    if log {
        let (l0, l1) = (lo.log10(), hi.log10());
        let pad = ((l1 - l0) * 0.08).max(0.1);
        return Some((10f64.powf(l0 - pad), 10f64.powf(l1 + pad)));
    }
    let pad = ((hi - lo) * 0.08).max(hi.abs().max(1.0) * 0.02);
    Some((lo - pad, hi + pad))
}

/// Writes `series` as a line-and-point chart to `path` (PNG, 800x560). Points with a non-finite
/// coordinate (or a coordinate <= 0 on a log axis) are left out; a chart with no point left is an error
/// naming the file.
pub fn write_chart(path: &Path, chart: &Chart, series: &[Series]) -> Result<()> {
    register_font()?;
    let keep =
        |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite() && (!chart.log_x || x > 0.0) && (!chart.log_y || y > 0.0);
    let series: Vec<Series> = series
        .iter()
        .map(|s| {
            let (points, labels): (Vec<_>, Vec<_>) = s
                .points
                .iter()
                .enumerate()
                .filter(|(_, p)| keep(p))
                .map(|(i, p)| (*p, s.labels.get(i).cloned().unwrap_or_default()))
                .unzip();
            Series { name: s.name.clone(), points, labels }
        })
        .filter(|s| !s.points.is_empty())
        .collect();
    let all = || series.iter().flat_map(|s| s.points.iter().copied());
    if all().next().is_none() {
        bail!("{}: no finite point to plot (a log axis leaves out points <= 0)", path.display());
    }
    // A log axis within one decade gets no tick labels: such data is drawn on a linear axis.
    let spans_decade = |v: Vec<f64>| {
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max) > 10.0 * v.iter().copied().fold(f64::INFINITY, f64::min)
    };
    let log_x = chart.log_x && spans_decade(all().map(|p| p.0).collect());
    let log_y = chart.log_y && spans_decade(all().map(|p| p.1).collect());
    let (Some(xr), Some(yr)) = (range(all().map(|p| p.0), log_x), range(all().map(|p| p.1), log_y)) else {
        bail!("{}: no finite point to plot (a log axis leaves out points <= 0)", path.display());
    };
    let corner = legend_corner(&series, xr, yr, log_x, log_y);
    let (x, y) = (xr.0..xr.1, yr.0..yr.1);
    let res = match (log_x, log_y) {
        (true, true) => draw(path, chart, &series, x.log_scale(), y.log_scale(), corner),
        (true, false) => draw(path, chart, &series, x.log_scale(), y, corner),
        (false, true) => draw(path, chart, &series, x, y.log_scale(), corner),
        (false, false) => draw(path, chart, &series, x, y, corner),
    };
    res.with_context(|| format!("writing chart {}", path.display()))
}

/// The corner of the plot with the fewest points (the legend box goes there and hides least).
fn legend_corner(series: &[Series], xr: (f64, f64), yr: (f64, f64), log_x: bool, log_y: bool) -> SeriesLabelPosition {
    let unit = |v: f64, r: (f64, f64), log: bool| {
        if log {
            (v.ln() - r.0.ln()) / (r.1.ln() - r.0.ln())
        } else {
            (v - r.0) / (r.1 - r.0)
        }
    };
    let fx = |x: f64| unit(x, xr, log_x);
    let fy = |y: f64| unit(y, yr, log_y);
    let count = |right: bool, upper: bool| {
        series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|&&(x, y)| {
                let (u, v) = (fx(x), fy(y));
                (if right { u > 0.55 } else { u < 0.45 }) && (if upper { v > 0.55 } else { v < 0.45 })
            })
            .count()
    };
    [
        (SeriesLabelPosition::LowerRight, count(true, false)),
        (SeriesLabelPosition::UpperRight, count(true, true)),
        (SeriesLabelPosition::UpperLeft, count(false, true)),
        (SeriesLabelPosition::LowerLeft, count(false, false)),
    ]
    .into_iter()
    .min_by_key(|c| c.1)
    .map(|c| c.0)
    .unwrap_or(SeriesLabelPosition::LowerRight)
}

fn draw<X, Y>(path: &Path, chart: &Chart, series: &[Series], x: X, y: Y, corner: SeriesLabelPosition) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let root = BitMapBackend::new(path, (800, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, (FAMILY, 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)
        .map_err(|e| anyhow!("{e}"))?;
    c.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .x_labels(7)
        .y_labels(8)
        .label_style((FAMILY, 13))
        .axis_desc_style((FAMILY, 15))
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    for (i, s) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        c.draw_series(LineSeries::new(s.points.iter().copied(), color.stroke_width(2)))
            .map_err(|e| anyhow!("{e}"))?
            .label(&s.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
        c.draw_series(s.points.iter().map(|&p| Circle::new(p, 4, color.filled()))).map_err(|e| anyhow!("{e}"))?;
        let text = TextStyle::from((FAMILY, 12)).color(&BLACK);
        c.draw_series(
            s.points
                .iter()
                .zip(&s.labels)
                .filter(|(_, l)| !l.is_empty())
                .map(|(&p, l)| Text::new(l.clone(), p, text.clone())),
        )
        .map_err(|e| anyhow!("{e}"))?;
    }
    if chart.legend {
        c.configure_series_labels()
            .position(corner)
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Writes a horizontal bar chart of `bars` (label, value; drawn top to bottom in the given
/// order, each annotated with its label and value in `unit`) to `path` (PNG, 800 wide). Bars
/// with a non-finite or negative value are drawn empty and annotated "n/a".
pub fn write_bars(path: &Path, title: &str, unit: &str, bars: &[(String, f64)]) -> Result<()> {
    register_font()?;
    if bars.is_empty() {
        bail!("{}: no bar to draw", path.display());
    }
    let ok = |v: f64| v.is_finite() && v >= 0.0;
    let max = bars.iter().map(|b| b.1).filter(|&v| ok(v)).fold(0.0f64, f64::max).max(1e-9);
    let n = bars.len();
    let height = (90 + 22 * n).min(4000) as u32;
    let res = (|| -> Result<()> {
        let root = BitMapBackend::new(path, (800, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let mut c = ChartBuilder::on(&root)
            .caption(title, (FAMILY, 18))
            .margin(12)
            .x_label_area_size(36)
            .build_cartesian_2d(0.0..max * 1.9, 0.0..n as f64)
            .map_err(|e| anyhow!("{e}"))?;
        c.configure_mesh()
            .disable_y_mesh()
            .disable_y_axis()
            .x_labels(8)
            .x_desc(unit)
            .label_style((FAMILY, 12))
            .axis_desc_style((FAMILY, 14))
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        let color = Palette99::pick(4).to_rgba();
        let top = |i: usize| (n - i) as f64;
        c.draw_series(
            bars.iter()
                .enumerate()
                .filter(|(_, b)| ok(b.1))
                .map(|(i, b)| Rectangle::new([(0.0, top(i) - 0.15), (b.1, top(i) - 0.85)], color.filled())),
        )
        .map_err(|e| anyhow!("{e}"))?;
        let text = TextStyle::from((FAMILY, 12)).color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
        c.draw_series(bars.iter().enumerate().map(|(i, b)| {
            let value = if ok(b.1) { format!("{:.3} {unit}", b.1) } else { "n/a".into() };
            let x = if ok(b.1) { b.1 } else { 0.0 };
            Text::new(format!(" {}  {value}", b.0), (x, top(i) - 0.5), text.clone())
        }))
        .map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{e}"))?;
        Ok(())
    })();
    res.with_context(|| format!("writing chart {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = std::fs::read(path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        (u32::from_be_bytes(bytes[16..20].try_into().unwrap()), u32::from_be_bytes(bytes[20..24].try_into().unwrap()))
    }

    #[test]
    fn writes_png_and_drops_bad_points() {
        let dir = std::env::temp_dir().join(format!("penumbra-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let s = vec![
            Series {
                name: "a".into(),
                points: vec![(1.0, 20.0), (10.0, 25.0), (f64::NAN, 3.0), (-1.0, 4.0)],
                labels: vec!["x".into(), "y".into()],
            },
            Series { name: "b".into(), points: vec![(100.0, 30.0)], labels: vec![] },
        ];
        for log_x in [false, true] {
            let p = dir.join(format!("c{log_x}.png"));
            let chart = Chart::new("t", "ms", "dB").log(log_x, false).legend(!log_x);
            write_chart(&p, &chart, &s).unwrap();
            assert_eq!(png_size(&p), (800, 560));
        }
        // log-log (an error front): y <= 0 left out, a y span over a decade on a log axis; a
        // chart whose only positive y values are gone is an error
        let e = vec![Series {
            name: "err".into(),
            points: vec![(1.0, 0.9), (30.0, 0.02), (100.0, 0.0), (300.0, -0.1)],
            labels: vec![],
        }];
        let p = dir.join("loglog.png");
        let chart = Chart::new("t", "ms", "e").log(true, true);
        write_chart(&p, &chart, &e).unwrap();
        assert_eq!(png_size(&p), (800, 560));
        let zeros = [Series { name: "z".into(), points: vec![(1.0, 0.0), (2.0, -1.0)], labels: vec![] }];
        assert!(write_chart(&p, &chart, &zeros).unwrap_err().to_string().contains("no finite point"));
        let p = dir.join("empty.png");
        let chart = Chart::new("t", "ms", "dB").log(true, false);
        let bad = [Series { name: "n".into(), points: vec![(0.0, 1.0), (f64::INFINITY, 2.0)], labels: vec![] }];
        let err = write_chart(&p, &chart, &bad).unwrap_err().to_string();
        assert!(err.contains("empty.png") && err.contains("no finite point"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bars_grow_with_the_count_and_empty_is_an_error() {
        let dir = std::env::temp_dir().join(format!("penumbra-bars-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bars: Vec<(String, f64)> =
            vec![("gbuffer".into(), 1.5), ("shade".into(), 12.0), ("bad".into(), f64::NAN), ("neg".into(), -1.0)];
        let p = dir.join("b.png");
        write_bars(&p, "t", "ms", &bars).unwrap();
        assert_eq!(png_size(&p), (800, 90 + 22 * 4));
        let err = write_bars(&dir.join("e.png"), "t", "ms", &[]).unwrap_err().to_string();
        assert!(err.contains("e.png") && err.contains("no bar"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
