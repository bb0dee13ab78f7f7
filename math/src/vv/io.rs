//! The `.pvv` file format (little endian):
//!
//! ```text
//! magic "PNVV", version u32 (= FORMAT_VERSION), model_hash u64, vertex_count u32, triangle_count u32,
//! params: resolution u32, refine_steps u32, tolerance_deg f32, max_segment_deg f32, max_link_deg f32, seed u64,
//! stats: visibility_seconds f64, correspondence_seconds f64, voronoi u32, propagated u32, relaxed u32, pole u32,
//! counts: points u32, vertex_points u32, sequences u32, loops u32, triples u32,
//! points [f32; 4] x points, seq_offsets u32 x (sequences + 1), vertex_seqs [u32; 2] x vertex_count,
//! tri_offsets u32 x (triangle_count + 1), loop_offsets u32 x (loops + 1), triples [u32; 3] x triples
//! ```
//!
//! Every offset array must start at 0, be non-decreasing and end at the length it indexes;
//! every index must be in range; points must be finite with `w` 0 or 1.

use super::*;
use std::path::Path;

/// Version of the `.pvv` format this build reads and writes.
pub const FORMAT_VERSION: u32 = 2;

/// Largest element count accepted in a file (guards allocations on corrupt input).
const MAX_COUNT: u32 = 1 << 28;

impl VvData {
    /// Serializes (see the `io` module docs for the layout).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::new();
        let u = |b: &mut Vec<u8>, v: u32| b.extend_from_slice(&v.to_le_bytes());
        b.extend_from_slice(MAGIC);
        u(&mut b, FORMAT_VERSION);
        b.extend_from_slice(&self.model_hash.to_le_bytes());
        u(&mut b, self.vertex_count);
        u(&mut b, self.triangle_count);
        let p = &self.params;
        u(&mut b, p.resolution);
        u(&mut b, p.refine_steps);
        b.extend_from_slice(&p.tolerance_deg.to_le_bytes());
        b.extend_from_slice(&p.max_segment_deg.to_le_bytes());
        b.extend_from_slice(&p.max_link_deg.to_le_bytes());
        b.extend_from_slice(&p.seed.to_le_bytes());
        b.extend_from_slice(&self.stats.visibility_seconds.to_le_bytes());
        b.extend_from_slice(&self.stats.correspondence_seconds.to_le_bytes());
        u(&mut b, self.stats.voronoi_triples as u32);
        u(&mut b, self.stats.propagated_triples as u32);
        u(&mut b, self.stats.relaxed_triples as u32);
        u(&mut b, self.stats.pole_triples as u32);
        let (v, c) = (&self.vis, &self.corr);
        u(&mut b, v.points.len() as u32);
        u(&mut b, v.vertex_points);
        u(&mut b, v.sequence_count() as u32);
        u(&mut b, c.loop_offsets.len().saturating_sub(1) as u32);
        u(&mut b, c.triples.len() as u32);
        for q in &v.points {
            for x in q {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        v.seq_offsets.iter().for_each(|&x| u(&mut b, x));
        v.vertex_seqs.iter().flatten().for_each(|&x| u(&mut b, x));
        c.tri_offsets.iter().for_each(|&x| u(&mut b, x));
        c.loop_offsets.iter().for_each(|&x| u(&mut b, x));
        c.triples.iter().flatten().for_each(|&x| u(&mut b, x));
        b
    }

    /// Parses [`VvData::to_bytes`]; `name` (the file) prefixes every error. Never panics.
    pub fn from_bytes(b: &[u8], name: &str) -> Result<Self, String> {
        let err = |m: String| format!("{name}: {m}");
        let mut r = Reader { b, pos: 0 };
        if r.take(4).map_err(err)? != MAGIC {
            return Err(err("not a vectorized-visibility file (bad magic, expected PNVV)".into()));
        }
        let version = r.u32().map_err(err)?;
        if version != FORMAT_VERSION {
            return Err(err(format!(
                "format version {version}, this build reads version {FORMAT_VERSION} (re-run `penumbra precompute vv`)"
            )));
        }
        let model_hash = r.u64().map_err(err)?;
        let vertex_count = r.count("vertex count").map_err(err)?;
        let triangle_count = r.count("triangle count").map_err(err)?;
        let params = VvParams {
            resolution: r.u32().map_err(err)?,
            refine_steps: r.u32().map_err(err)?,
            tolerance_deg: r.f32().map_err(err)?,
            max_segment_deg: r.f32().map_err(err)?,
            max_link_deg: r.f32().map_err(err)?,
            seed: r.u64().map_err(err)?,
        };
        params.validate().map_err(err)?;
        let mut stats = VvStats {
            visibility_seconds: r.f64().map_err(err)?,
            correspondence_seconds: r.f64().map_err(err)?,
            ..Default::default()
        };
        stats.voronoi_triples = r.u32().map_err(err)? as usize;
        stats.propagated_triples = r.u32().map_err(err)? as usize;
        stats.relaxed_triples = r.u32().map_err(err)? as usize;
        stats.pole_triples = r.u32().map_err(err)? as usize;
        let npoints = r.count("point count").map_err(err)?;
        let vertex_points = r.count("vertex point count").map_err(err)?;
        let nseq = r.count("sequence count").map_err(err)?;
        let nloops = r.count("loop count").map_err(err)?;
        let ntriples = r.count("triple count").map_err(err)?;
        if vertex_points > npoints {
            return Err(err(format!("{vertex_points} vertex points > {npoints} points")));
        }
        let need = 16 * npoints as u64
            + 4 * (nseq as u64 + 1)
            + 8 * vertex_count as u64
            + 4 * (triangle_count as u64 + 1)
            + 4 * (nloops as u64 + 1)
            + 12 * ntriples as u64;
        let have = (b.len() - r.pos) as u64;
        if have < need {
            return Err(err(format!("truncated: {have} bytes of arrays, the header announces {need}")));
        }
        if have > need {
            return Err(err(format!("{} trailing bytes after the arrays", have - need)));
        }
        let mut points = Vec::with_capacity(npoints as usize);
        for i in 0..npoints {
            let q = [r.f32().map_err(err)?, r.f32().map_err(err)?, r.f32().map_err(err)?, r.f32().map_err(err)?];
            if !q.iter().all(|x| x.is_finite()) || !(q[3] == 0.0 || q[3] == 1.0) {
                return Err(err(format!("point {i} is not finite or has w not 0/1: {q:?}")));
            }
            points.push(q);
        }
        let seq_offsets = r.u32s(nseq as usize + 1).map_err(err)?;
        check_offsets(&seq_offsets, vertex_points, "sequence offsets").map_err(err)?;
        let flat = r.u32s(2 * vertex_count as usize).map_err(err)?;
        let vertex_seqs: Vec<[u32; 2]> = flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        for (v, s) in vertex_seqs.iter().enumerate() {
            if s[0] as u64 + s[1] as u64 > nseq as u64 {
                return Err(err(format!(
                    "vertex {v}: sequences {}..{} out of range ({nseq} sequences)",
                    s[0],
                    s[0] as u64 + s[1] as u64
                )));
            }
        }
        let tri_offsets = r.u32s(triangle_count as usize + 1).map_err(err)?;
        check_offsets(&tri_offsets, nloops, "triangle offsets").map_err(err)?;
        let loop_offsets = r.u32s(nloops as usize + 1).map_err(err)?;
        check_offsets(&loop_offsets, ntriples, "loop offsets").map_err(err)?;
        let flat = r.u32s(3 * ntriples as usize).map_err(err)?;
        if let Some(i) = flat.iter().position(|&x| x >= npoints) {
            return Err(err(format!("triple {} references point {} ({npoints} points)", i / 3, flat[i])));
        }
        let triples = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(VvData {
            model_hash,
            vertex_count,
            triangle_count,
            params,
            vis: VectorizedVisibility { points, vertex_points, seq_offsets, vertex_seqs },
            corr: Correspondence { tri_offsets, loop_offsets, triples },
            stats: VvStats { visibility_bytes: 0, triple_bytes: 0, ..stats },
        }
        .with_sizes())
    }

    /// Fills the byte sizes of [`VvStats`] from the arrays.
    pub fn with_sizes(mut self) -> Self {
        self.stats.visibility_bytes =
            self.vis.points.len() * 16 + self.vis.seq_offsets.len() * 4 + self.vis.vertex_seqs.len() * 8;
        self.stats.triple_bytes = self.corr.triple_bytes();
        self
    }

    /// Reads a file (errors name it).
    pub fn read(path: &Path) -> Result<Self, String> {
        let b = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::from_bytes(&b, &path.display().to_string())
    }

    /// Reads a file and checks it was made for `model` (errors name the file).
    pub fn read_for(path: &Path, model: &VvModel) -> Result<Self, String> {
        let d = Self::read(path)?;
        d.check_model(model).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(d)
    }

    /// Whether this data belongs to `model` (counts and hash).
    pub fn check_model(&self, model: &VvModel) -> Result<(), String> {
        if self.vertex_count as usize != model.positions.len() || self.triangle_count as usize != model.triangle_count()
        {
            return Err(format!(
                "made for a model of {} vertices / {} triangles, this one has {} / {}",
                self.vertex_count,
                self.triangle_count,
                model.positions.len(),
                model.triangle_count()
            ));
        }
        if self.model_hash != model.hash() {
            return Err("made for a different model (hash mismatch): re-run `penumbra precompute vv`".into());
        }
        Ok(())
    }

    /// Writes the file (errors name it): beside it first, then renamed over it, so that a
    /// reader (another process sharing a cache directory) never sees half a file.
    pub fn write(&self, path: &Path) -> Result<(), String> {
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        std::fs::write(&tmp, self.to_bytes()).map_err(|e| format!("{}: {e}", tmp.display()))?;
        std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            format!("{}: {e}", path.display())
        })
    }
}

fn check_offsets(o: &[u32], end: u32, what: &str) -> Result<(), String> {
    if o.first() != Some(&0) {
        return Err(format!("{what} do not start at 0"));
    }
    if let Some(i) = o.windows(2).position(|w| w[1] < w[0]) {
        return Err(format!("{what} decrease at {i}"));
    }
    if o.last() != Some(&end) {
        return Err(format!("{what} end at {:?}, expected {end}", o.last()));
    }
    Ok(())
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| format!("truncated header (at byte {} of {})", self.pos, self.b.len()))?;
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn count(&mut self, what: &str) -> Result<u32, String> {
        let n = self.u32()?;
        if n > MAX_COUNT {
            return Err(format!("{what} {n} exceeds {MAX_COUNT} (corrupt header)"));
        }
        Ok(n)
    }
    fn u32s(&mut self, n: usize) -> Result<Vec<u32>, String> {
        let s = self.take(4 * n)?;
        Ok(s.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect())
    }
}
