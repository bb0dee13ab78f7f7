//! Per-pass GPU timings (from timestamp queries written by the executor around every pass) and
//! CPU timings of graph compilation and recording, aggregated over frames.

use serde::Serialize;
use std::collections::BTreeMap;

/// Aggregate of one pass (or CPU phase) over the frames it ran in.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PassStats {
    pub median_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
    pub samples: usize,
}

impl PassStats {
    pub fn from_samples(samples: &[f64]) -> Option<Self> {
        if samples.is_empty() {
            return None;
        }
        let mut v = samples.to_vec();
        v.sort_by(|a, b| a.total_cmp(b));
        let n = v.len();
        let median = if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) };
        Some(PassStats { median_ms: median, min_ms: v[0], max_ms: v[n - 1], samples: n })
    }
}

/// Collects samples per name, in first-seen order.
#[derive(Default, Debug, Clone)]
pub struct Profiler {
    order: Vec<String>,
    gpu: BTreeMap<String, Vec<f64>>,
    cpu: BTreeMap<String, Vec<f64>>,
    frames: usize,
}

/// Samples kept per pass or phase: statistics are over the last this many frames, so a
/// renderer that runs for hours holds a bounded profile.
pub const PROFILE_WINDOW: usize = 1024;

fn push_bounded(v: &mut Vec<f64>, ms: f64) {
    if v.len() >= PROFILE_WINDOW {
        v.drain(..v.len() + 1 - PROFILE_WINDOW);
    }
    v.push(ms);
}

impl Profiler {
    pub fn add_gpu(&mut self, pass: &str, ms: f64) {
        if !self.gpu.contains_key(pass) {
            self.order.push(pass.to_string());
        }
        push_bounded(self.gpu.entry(pass.to_string()).or_default(), ms);
    }
    pub fn add_cpu(&mut self, phase: &str, ms: f64) {
        push_bounded(self.cpu.entry(phase.to_string()).or_default(), ms);
    }
    pub fn end_frame(&mut self) {
        self.frames += 1;
    }
    /// Forgets every sample (e.g. after warm-up frames: lavapipe compiles a pipeline's shader at
    /// its first dispatch, which lands in that pass's first GPU timestamp interval).
    pub fn reset(&mut self) {
        *self = Profiler::default();
    }
    pub fn frames(&self) -> usize {
        self.frames
    }
    pub fn gpu_stats(&self) -> BTreeMap<String, PassStats> {
        self.gpu.iter().filter_map(|(k, v)| PassStats::from_samples(v).map(|s| (k.clone(), s))).collect()
    }
    pub fn cpu_stats(&self) -> BTreeMap<String, PassStats> {
        self.cpu.iter().filter_map(|(k, v)| PassStats::from_samples(v).map(|s| (k.clone(), s))).collect()
    }

    /// `profile.json`: GPU ms per pass (recording order) and CPU ms per phase.
    pub fn to_json(&self) -> serde_json::Value {
        let gpu = self.gpu_stats();
        let passes: Vec<serde_json::Value> =
            self.order.iter().filter_map(|n| gpu.get(n).map(|s| serde_json::json!({"pass": n, "gpu_ms": s}))).collect();
        let total: f64 = gpu.values().map(|s| s.median_ms).sum();
        serde_json::json!({
            "frames": self.frames,
            "passes": passes,
            "gpu_total_median_ms": total,
            "cpu_ms": self.cpu_stats(),
        })
    }

    /// A printed table.
    pub fn table(&self) -> String {
        let gpu = self.gpu_stats();
        let mut s =
            format!("{:<28} {:>10} {:>10} {:>10} {:>7}\n", "pass (GPU)", "median ms", "min ms", "max ms", "frames");
        for n in &self.order {
            if let Some(t) = gpu.get(n) {
                s += &format!(
                    "{:<28} {:>10.3} {:>10.3} {:>10.3} {:>7}\n",
                    n, t.median_ms, t.min_ms, t.max_ms, t.samples
                );
            }
        }
        for (n, t) in self.cpu_stats() {
            s += &format!(
                "{:<28} {:>10.3} {:>10.3} {:>10.3} {:>7}\n",
                format!("cpu: {n}"),
                t.median_ms,
                t.min_ms,
                t.max_ms,
                t.samples
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn the_profile_keeps_a_bounded_window() {
        let mut p = Profiler::default();
        for i in 0..PROFILE_WINDOW + 500 {
            p.add_gpu("pass", i as f64);
            p.add_cpu("record", 1.0);
        }
        let s = p.gpu_stats()["pass"].clone();
        assert_eq!(s.samples, PROFILE_WINDOW);
        assert_eq!(s.min_ms, 500.0, "the oldest samples go first");
        assert_eq!(p.cpu_stats()["record"].samples, PROFILE_WINDOW);
    }

    #[test]
    fn median_min_max() {
        let s = PassStats::from_samples(&[3.0, 1.0, 2.0, 10.0]).unwrap();
        assert_eq!((s.median_ms, s.min_ms, s.max_ms, s.samples), (2.5, 1.0, 10.0, 4));
        let s = PassStats::from_samples(&[5.0, 1.0, 2.0]).unwrap();
        assert_eq!(s.median_ms, 2.0);
        assert!(PassStats::from_samples(&[]).is_none());
    }
}
