//! Triangle meshes and procedural primitives.

use glam::{Vec2, Vec3};
use std::f32::consts::{PI, TAU};

/// An indexed triangle mesh in object space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshData {
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Unit normals, one per vertex.
    pub normals: Vec<Vec3>,
    /// Texture coordinates, one per vertex.
    pub uvs: Vec<Vec2>,
    /// Triangle list, counter-clockwise seen from outside.
    pub indices: Vec<u32>,
}

impl MeshData {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Same vertex positions and triangles (the same procedural ball on several objects): what
    /// depends on shape only (shadow fields, sphere sets) is computed once for such meshes.
    pub fn same_shape(&self, other: &MeshData) -> bool {
        self.positions == other.positions && self.indices == other.indices
    }

    /// Axis-aligned bounds (min, max); `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p))))
    }

    /// A square in the XZ plane centred at the origin, normal +Y, `n` x `n` quads.
    pub fn plane(size: f32, n: u32) -> Self {
        let n = n.max(1);
        let mut m = MeshData { name: "plane".into(), ..Default::default() };
        for j in 0..=n {
            for i in 0..=n {
                let u = i as f32 / n as f32;
                let v = j as f32 / n as f32;
                m.positions.push(Vec3::new((u - 0.5) * size, 0.0, (v - 0.5) * size));
                m.normals.push(Vec3::Y);
                m.uvs.push(Vec2::new(u, v) * size);
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                let b = a + 1;
                let c = a + n + 1;
                let d = c + 1;
                m.indices.extend_from_slice(&[a, c, b, b, c, d]);
            }
        }
        m
    }

    /// A UV sphere of radius `r` centred at the origin.
    pub fn uv_sphere(r: f32, slices: u32, stacks: u32) -> Self {
        let (slices, stacks) = (slices.max(3), stacks.max(2));
        let mut m = MeshData { name: "sphere".into(), ..Default::default() };
        for j in 0..=stacks {
            let v = j as f32 / stacks as f32;
            let theta = v * PI;
            for i in 0..=slices {
                let u = i as f32 / slices as f32;
                let phi = u * TAU;
                let n = Vec3::new(theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin());
                m.positions.push(n * r);
                m.normals.push(n);
                m.uvs.push(Vec2::new(u, v));
            }
        }
        for j in 0..stacks {
            for i in 0..slices {
                let a = j * (slices + 1) + i;
                let b = a + slices + 1;
                if j != 0 {
                    m.indices.extend_from_slice(&[a, b, a + 1]);
                }
                if j != stacks - 1 {
                    m.indices.extend_from_slice(&[a + 1, b, b + 1]);
                }
            }
        }
        m
    }

    /// An axis-aligned cube with half extent `h`, flat-shaded faces.
    pub fn cube(h: f32) -> Self {
        let mut m = MeshData { name: "cube".into(), ..Default::default() };
        let axes = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z];
        for n in axes {
            let t = if n.y.abs() > 0.5 { Vec3::X } else { Vec3::Y };
            let s = n.cross(t);
            let base = m.positions.len() as u32;
            for (du, dv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                m.positions.push((n + s * du + t * dv) * h);
                m.normals.push(n);
                m.uvs.push(Vec2::new((du + 1.0) * 0.5, (dv + 1.0) * 0.5));
            }
            // (s, t, n) is right-handed: s x t = n x t x t ... ensure CCW seen from outside.
            let ccw = s.cross(t).dot(n) > 0.0;
            if ccw {
                m.indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
            } else {
                m.indices.extend_from_slice(&[base, base + 2, base + 1, base, base + 3, base + 2]);
            }
        }
        m
    }

    /// A torus around +Y with major radius `big_r` and tube radius `r`.
    pub fn torus(big_r: f32, r: f32, major: u32, minor: u32) -> Self {
        let (major, minor) = (major.max(3), minor.max(3));
        let mut m = MeshData { name: "torus".into(), ..Default::default() };
        for j in 0..=major {
            let u = j as f32 / major as f32;
            let a = u * TAU;
            let c = Vec3::new(a.cos(), 0.0, -a.sin());
            for i in 0..=minor {
                let v = i as f32 / minor as f32;
                let b = v * TAU;
                let n = c * b.cos() + Vec3::Y * b.sin();
                m.positions.push(c * big_r + n * r);
                m.normals.push(n);
                m.uvs.push(Vec2::new(u, v));
            }
        }
        for j in 0..major {
            for i in 0..minor {
                let a = j * (minor + 1) + i;
                let b = a + minor + 1;
                m.indices.extend_from_slice(&[a, b, a + 1, a + 1, b, b + 1]);
            }
        }
        m
    }
}

/// Edge statistics of a mesh after welding coincident vertices (see [`MeshData::weld_ids`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EdgeStats {
    /// Edges used by exactly one triangle (holes, open borders).
    pub boundary: usize,
    /// Edges shared by more than two triangles.
    pub non_manifold: usize,
}

impl MeshData {
    /// Boundary and non-manifold edge counts. Coincident vertices are welded
    /// first, so UV / normal seams do not count as borders.
    pub fn edge_stats(&self) -> EdgeStats {
        use std::collections::HashMap;
        let ids = self.weld_ids();
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in self.indices.chunks_exact(3) {
            let v = [t[0], t[1], t[2]].map(|i| ids.get(i as usize).copied().unwrap_or(u32::MAX));
            if v[0] == v[1] || v[1] == v[2] || v[0] == v[2] {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (v[k], v[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        let mut s = EdgeStats::default();
        for &c in edges.values() {
            if c == 1 {
                s.boundary += 1;
            } else if c > 2 {
                s.non_manifold += 1;
            }
        }
        s
    }

    /// For each vertex, the id of its welded vertex: vertices closer than 1e-6 of the bounding
    /// box diagonal share an id.
    pub fn weld_ids(&self) -> Vec<u32> {
        use std::collections::HashMap;
        let Some((lo, hi)) = self.bounds() else { return Vec::new() };
        let eps = ((hi - lo).length() * 1e-6).max(1e-12);
        let cell = |p: Vec3| {
            let q = ((p - lo) / eps).floor();
            [q.x as i64, q.y as i64, q.z as i64]
        };
        let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        let mut ids = Vec::with_capacity(self.positions.len());
        let mut reps: Vec<Vec3> = Vec::new();
        for p in &self.positions {
            let c = cell(*p);
            let mut found = None;
            'search: for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(v) = grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            for &r in v {
                                if reps[r as usize].distance(*p) <= eps {
                                    found = Some(r);
                                    break 'search;
                                }
                            }
                        }
                    }
                }
            }
            let id = found.unwrap_or_else(|| {
                reps.push(*p);
                let r = reps.len() as u32 - 1;
                grid.entry(c).or_default().push(r);
                r
            });
            ids.push(id);
        }
        ids
    }

    /// True when the mesh is a closed 2-manifold (no boundary or non-manifold edges), as
    /// techniques that need an inside/outside (closed occluders) require.
    pub fn is_closed(&self) -> bool {
        !self.indices.is_empty() && self.edge_stats() == EdgeStats::default()
    }

    /// Whether the mesh is closed, wound counter-clockwise seen from outside (positive signed
    /// volume), with its vertex normals on the same side (a triangle's normal against the sum of
    /// its vertex normals, agreeing over at least 95 % of the area). Then a triangle seen from
    /// its back (by winding) is hidden behind the mesh's front except where a silhouette's
    /// coverage comes down to rounding, and a rasterizer may cull it: a ray through that pixel
    /// centre goes past the silhouette.
    pub fn is_closed_outward(&self) -> bool {
        if !self.is_closed() {
            return false;
        }
        let np = self.positions.len();
        let has_n = self.normals.len() == np;
        let (mut volume, mut agree, mut total) = (0.0f64, 0.0f64, 0.0f64);
        for t in self.indices.chunks_exact(3) {
            let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
            if a >= np || b >= np || c >= np {
                return false;
            }
            let (pa, pb, pc) = (self.positions[a], self.positions[b], self.positions[c]);
            volume += f64::from(pa.dot(pb.cross(pc)));
            let g = (pb - pa).cross(pc - pa);
            let area = f64::from(g.length());
            total += area;
            if !has_n || g.dot(self.normals[a] + self.normals[b] + self.normals[c]) > 0.0 {
                agree += area;
            }
        }
        volume > 0.0 && total > 0.0 && agree >= 0.95 * total
    }

    /// Area-weighted smooth vertex normals from the triangles (vertices without a
    /// non-degenerate triangle get +Y).
    pub fn recompute_normals(&mut self) {
        let mut n = vec![Vec3::ZERO; self.positions.len()];
        for t in self.indices.chunks_exact(3) {
            let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
            if a >= n.len() || b >= n.len() || c >= n.len() {
                continue;
            }
            let g = (self.positions[b] - self.positions[a]).cross(self.positions[c] - self.positions[a]);
            n[a] += g;
            n[b] += g;
            n[c] += g;
        }
        self.normals = n.into_iter().map(|v| v.try_normalize().unwrap_or(Vec3::Y)).collect();
    }

    /// Check the mesh and repair what is degenerate but renderable.
    ///
    /// Errors (returned as a message without the file name; the caller adds it): no triangles,
    /// index count not a multiple of 3, indices out of range, NaN/Inf positions, attribute
    /// arrays of the wrong length. Repairs (one warning each, pushed to `warnings`, prefixed
    /// with `label`): zero-area triangles removed, missing or non-finite or zero normals
    /// recomputed, unnormalized normals normalized, missing UVs set to 0, non-finite UVs zeroed.
    pub fn validate_and_repair(&mut self, label: &str, warnings: &mut Vec<String>) -> Result<(), String> {
        let nv = self.positions.len();
        if nv == 0 || self.indices.is_empty() {
            return Err(format!("mesh '{}' has no triangles", self.name));
        }
        if !self.indices.len().is_multiple_of(3) {
            return Err(format!("mesh '{}': index count {} is not a multiple of 3", self.name, self.indices.len()));
        }
        if let Some((k, &i)) = self.indices.iter().enumerate().find(|(_, &i)| i as usize >= nv) {
            return Err(format!(
                "mesh '{}': index {} at position {} is out of range ({} vertices)",
                self.name, i, k, nv
            ));
        }
        if let Some((k, p)) = self.positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(format!("mesh '{}': vertex {} has a non-finite position (NaN/Inf) {:?}", self.name, k, p));
        }
        /// Coordinates beyond this are rejected: products with transforms would overflow f32.
        const MAX_COORD: f32 = 1e15;
        if let Some((k, p)) = self.positions.iter().enumerate().find(|(_, p)| p.abs().max_element() > MAX_COORD) {
            return Err(format!(
                "mesh '{}': vertex {} has an out-of-range position {:?} (|coordinate| > 1e15)",
                self.name, k, p
            ));
        }
        if !self.normals.is_empty() && self.normals.len() != nv {
            return Err(format!("mesh '{}': {} normals for {} vertices", self.name, self.normals.len(), nv));
        }
        if !self.uvs.is_empty() && self.uvs.len() != nv {
            return Err(format!("mesh '{}': {} uvs for {} vertices", self.name, self.uvs.len(), nv));
        }
        // Zero-area triangles.
        let before = self.triangle_count();
        let pos = &self.positions;
        let mut kept = Vec::with_capacity(self.indices.len());
        for t in self.indices.chunks_exact(3) {
            let [a, b, c] = [pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]];
            let area2 = (b - a).cross(c - a).length();
            let scale = (b - a).length_squared().max((c - a).length_squared()).max(1e-30);
            if area2 > 1e-12 * scale && area2.is_finite() {
                kept.extend_from_slice(t);
            }
        }
        let removed = before - kept.len() / 3;
        if removed > 0 {
            warnings
                .push(format!("{label}: mesh '{}': removed {removed} zero-area triangle(s) of {before}", self.name));
            self.indices = kept;
        }
        if self.indices.is_empty() {
            return Err(format!("mesh '{}' has only zero-area triangles", self.name));
        }
        // Normals.
        if self.normals.is_empty() {
            warnings.push(format!("{label}: mesh '{}': no normals, computed smooth normals", self.name));
            self.recompute_normals();
        } else {
            let bad = self.normals.iter().filter(|n| !n.is_finite() || n.length_squared() < 1e-12).count();
            if bad > 0 {
                warnings.push(format!(
                    "{label}: mesh '{}': {bad} zero or non-finite normal(s), recomputed normals",
                    self.name
                ));
                let old = std::mem::take(&mut self.normals);
                self.recompute_normals();
                for (n, o) in self.normals.iter_mut().zip(old) {
                    if o.is_finite() && o.length_squared() >= 1e-12 {
                        *n = o;
                    }
                }
            }
            let unnorm = self.normals.iter().filter(|n| (n.length() - 1.0).abs() > 1e-3).count();
            if unnorm > 0 {
                warnings.push(format!("{label}: mesh '{}': normalized {unnorm} unnormalized normal(s)", self.name));
                for n in &mut self.normals {
                    *n = n.normalize();
                }
            }
        }
        if self.uvs.is_empty() {
            self.uvs = vec![Vec2::ZERO; nv];
        } else if self.uvs.iter().any(|u| !u.is_finite()) {
            warnings.push(format!("{label}: mesh '{}': non-finite texture coordinates set to 0", self.name));
            for u in &mut self.uvs {
                if !u.is_finite() {
                    *u = Vec2::ZERO;
                }
            }
        }
        Ok(())
    }

    /// Apply an affine transform to positions and normals.
    pub fn transformed(&self, m: glam::Mat4) -> MeshData {
        let nm = glam::Mat3::from_mat4(m).inverse().transpose();
        MeshData {
            name: self.name.clone(),
            positions: self.positions.iter().map(|p| m.transform_point3(*p)).collect(),
            normals: self.normals.iter().map(|n| (nm * *n).normalize_or_zero()).collect(),
            uvs: self.uvs.clone(),
            indices: self.indices.clone(),
        }
    }

    /// Splits every edge longer than `max_edge` at its midpoint, pass after pass, until no edge is
    /// longer or the next pass would exceed `max_triangles` (the mesh of the last complete pass
    /// is returned, so the cap never leaves a half-refined pass). A triangle with one split edge
    /// becomes two, with two becomes three (its quad cut along the shorter diagonal), with three
    /// becomes four. Whether an edge splits depends only on its end positions, so the triangles
    /// on both sides of an edge agree, also across uv seams (vertices duplicated with other
    /// attributes): the result has no T-junctions where the input had none. New vertices take
    /// the mean position and uv of the edge's ends and their normalised mean normal; winding is
    /// kept. Degenerate (zero-length) edges never split.
    pub fn refine_long_edges(&self, max_edge: f32, max_triangles: usize) -> MeshData {
        let mut m = self.clone();
        if !(max_edge > 0.0) || !max_edge.is_finite() {
            return m;
        }
        let has_uv = m.uvs.len() == m.positions.len();
        loop {
            let long =
                |m: &MeshData, a: u32, b: u32| (m.positions[a as usize] - m.positions[b as usize]).length() > max_edge;
            // count the triangles of the next pass first (the cap)
            let mut next = 0usize;
            let mut any = false;
            for t in m.indices.chunks_exact(3) {
                let k = (0..3).filter(|&i| long(&m, t[i], t[(i + 1) % 3])).count();
                any |= k > 0;
                next += k + 1;
            }
            if !any || next > max_triangles {
                return m;
            }
            let mut mid: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
            let mut midpoint = |m: &mut MeshData, a: u32, b: u32| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (pa, pb) = (m.positions[a as usize], m.positions[b as usize]);
                    let n = (m.normals[a as usize] + m.normals[b as usize]).normalize_or(m.normals[a as usize]);
                    m.positions.push((pa + pb) * 0.5);
                    m.normals.push(n);
                    if has_uv {
                        let uv = (m.uvs[a as usize] + m.uvs[b as usize]) * 0.5;
                        m.uvs.push(uv);
                    }
                    (m.positions.len() - 1) as u32
                })
            };
            let old = std::mem::take(&mut m.indices);
            let mut out = Vec::with_capacity(next * 3);
            for t in old.chunks_exact(3) {
                let split = [long(&m, t[0], t[1]), long(&m, t[1], t[2]), long(&m, t[2], t[0])];
                match split.iter().filter(|s| **s).count() {
                    0 => out.extend_from_slice(t),
                    1 => {
                        // rotate so the split edge is (a, b)
                        let r = split.iter().position(|s| *s).unwrap_or(0);
                        let (a, b, c) = (t[r], t[(r + 1) % 3], t[(r + 2) % 3]);
                        let ab = midpoint(&mut m, a, b);
                        out.extend_from_slice(&[a, ab, c, ab, b, c]);
                    }
                    2 => {
                        // rotate so the unsplit edge is (c, a): split edges (a, b) and (b, c)
                        let r = (split.iter().position(|s| !*s).unwrap_or(2) + 1) % 3;
                        let (a, b, c) = (t[r], t[(r + 1) % 3], t[(r + 2) % 3]);
                        let ab = midpoint(&mut m, a, b);
                        let bc = midpoint(&mut m, b, c);
                        out.extend_from_slice(&[ab, b, bc]);
                        // the quad a, ab, bc, c along its shorter diagonal
                        let p = |i: u32| m.positions[i as usize];
                        if (p(a) - p(bc)).length() <= (p(ab) - p(c)).length() {
                            out.extend_from_slice(&[a, ab, bc, a, bc, c]);
                        } else {
                            out.extend_from_slice(&[a, ab, c, ab, bc, c]);
                        }
                    }
                    _ => {
                        let (a, b, c) = (t[0], t[1], t[2]);
                        let (ab, bc, ca) = (midpoint(&mut m, a, b), midpoint(&mut m, b, c), midpoint(&mut m, c, a));
                        out.extend_from_slice(&[a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca]);
                    }
                }
            }
            m.indices = out;
        }
    }

    /// Surface of revolution around +Y of a profile of (radius, height) points listed from the
    /// bottom up (outside on the right when walking the profile). Profile points with radius 0
    /// become poles; a profile starting and ending on the axis gives a closed mesh.
    /// Normals are smooth along the profile.
    pub fn revolve(name: &str, profile: &[Vec2], segments: u32) -> Self {
        let seg = segments.max(3);
        let mut m = MeshData { name: name.into(), ..Default::default() };
        let np = profile.len();
        // Arc length for v.
        let mut acc = vec![0.0f32; np];
        for k in 1..np {
            acc[k] = acc[k - 1] + (profile[k] - profile[k - 1]).length();
        }
        let total = acc[np.saturating_sub(1)].max(1e-6);
        // Profile tangents -> 2D normals (outward when profile goes upward on the right side).
        let n2: Vec<Vec2> = (0..np)
            .map(|k| {
                let a = profile[k.saturating_sub(1)];
                let b = profile[(k + 1).min(np - 1)];
                let t = (b - a).normalize_or_zero();
                Vec2::new(t.y, -t.x).normalize_or(Vec2::Y)
            })
            .collect();
        for k in 0..np {
            for i in 0..=seg {
                let a = (i % seg) as f32 / seg as f32 * TAU;
                let (s, c) = a.sin_cos();
                let r = profile[k].x;
                m.positions.push(Vec3::new(r * c, profile[k].y, -r * s));
                let n = n2[k];
                m.normals.push(Vec3::new(n.x * c, n.y, -n.x * s).normalize_or(Vec3::Y));
                m.uvs.push(Vec2::new(i as f32 / seg as f32, acc[k] / total));
            }
        }
        let row = seg + 1;
        for k in 0..np.saturating_sub(1) as u32 {
            for i in 0..seg {
                let a = k * row + i;
                let b = a + 1;
                let c = a + row;
                let d = c + 1;
                // quad a b d c ; a at (k, i), c above it.
                let r0 = profile[k as usize].x;
                let r1 = profile[k as usize + 1].x;
                if r0 > 0.0 {
                    m.indices.extend_from_slice(&[a, b, d]);
                }
                if r1 > 0.0 {
                    m.indices.extend_from_slice(&[a, d, c]);
                }
            }
        }
        m
    }

    /// A cloth sheet in the XZ plane, `size_x` x `size_z`, `nx` x `nz` quads, with `folds`
    /// sinusoidal folds of height `fold_height` along X (draped folds). Open (thin shell).
    pub fn cloth(size_x: f32, size_z: f32, nx: u32, nz: u32, folds: f32, fold_height: f32) -> Self {
        let (nx, nz) = (nx.max(1), nz.max(1));
        let mut m = MeshData { name: "cloth".into(), ..Default::default() };
        let k = folds * TAU / size_x;
        for j in 0..=nz {
            for i in 0..=nx {
                let u = i as f32 / nx as f32;
                let v = j as f32 / nz as f32;
                let x = (u - 0.5) * size_x;
                let z = (v - 0.5) * size_z;
                // Folds fade towards the middle in z so the cloth looks draped.
                let w = 0.5 + 0.5 * (v * TAU).cos();
                let y = fold_height * (0.5 + 0.5 * (k * x).sin()) * (0.35 + 0.65 * w);
                m.positions.push(Vec3::new(x, y, z));
                m.uvs.push(Vec2::new(u, v));
            }
        }
        for j in 0..nz {
            for i in 0..nx {
                let a = j * (nx + 1) + i;
                let b = a + 1;
                let c = a + nx + 1;
                let d = c + 1;
                m.indices.extend_from_slice(&[a, c, b, b, c, d]);
            }
        }
        m.recompute_normals();
        m
    }

    /// A hat (crown and brim) as a closed surface of revolution, height `h`, brim radius `r`.
    pub fn hat(r: f32, h: f32, segments: u32) -> Self {
        Self::hat_refined(r, h, segments, 1)
    }

    /// [`MeshData::hat`] with each of its profile's 8 segments cut into `rings` (>= 1) equal
    /// pieces: the same shape, with vertices down its crown and across its brim (a lathe of the
    /// 9-point profile has none there, so a mesh at a paper's vertex count needs them).
    pub fn hat_refined(r: f32, h: f32, segments: u32, rings: u32) -> Self {
        let c = r * 0.55;
        let t = h * 0.04;
        let profile = [
            Vec2::new(0.0, 0.0),
            Vec2::new(r, 0.0),
            Vec2::new(r, t),
            Vec2::new(c * 1.02, t + 0.02 * h),
            Vec2::new(c, 0.3 * h),
            Vec2::new(c * 0.96, 0.8 * h),
            Vec2::new(c * 0.85, 0.95 * h),
            Vec2::new(c * 0.5, h),
            Vec2::new(0.0, h),
        ];
        let n = rings.max(1);
        let mut fine = vec![profile[0]];
        for w in profile.windows(2) {
            fine.extend((1..=n).map(|k| w[0].lerp(w[1], k as f32 / n as f32)));
        }
        Self::revolve("hat", &fine, segments)
    }

    /// A shallow dish (closed, with thickness) of radius `r` and depth `d`.
    pub fn dish(r: f32, d: f32, segments: u32, rings: u32) -> Self {
        let rings = rings.max(2);
        let thick = d * 0.15;
        let mut outer = Vec::new();
        outer.push(Vec2::new(0.0, 0.0));
        outer.push(Vec2::new(r * 0.5, 0.0));
        for k in 1..=rings {
            let s = k as f32 / rings as f32;
            let rr = r * (0.5 + 0.5 * s);
            outer.push(Vec2::new(rr, d * s * s));
        }
        let mut profile = outer.clone();
        profile.push(Vec2::new(r * 0.98, d + thick));
        for k in (0..=rings).rev() {
            let s = k as f32 / rings as f32;
            let rr = r * 0.96 * s;
            profile.push(Vec2::new(rr, thick + d * s * s));
        }
        // Last point (k = 0) is on the axis: closed.
        Self::revolve("dish", &profile, segments)
    }

    /// Chess pieces by revolution: "pawn", "rook", "bishop", "queen", "king". Height ~1.
    pub fn chess_piece(kind: &str, segments: u32) -> Option<Self> {
        let base = [Vec2::new(0.0, 0.0), Vec2::new(0.32, 0.0), Vec2::new(0.32, 0.06), Vec2::new(0.26, 0.1)];
        let top: Vec<Vec2> = match kind {
            "pawn" => vec![
                Vec2::new(0.14, 0.2),
                Vec2::new(0.1, 0.42),
                Vec2::new(0.16, 0.46),
                Vec2::new(0.09, 0.5),
                Vec2::new(0.13, 0.56),
                Vec2::new(0.14, 0.64),
                Vec2::new(0.1, 0.71),
                Vec2::new(0.0, 0.73),
            ],
            "rook" => vec![
                Vec2::new(0.18, 0.2),
                Vec2::new(0.15, 0.6),
                Vec2::new(0.22, 0.66),
                Vec2::new(0.22, 0.8),
                Vec2::new(0.16, 0.8),
                Vec2::new(0.16, 0.74),
                Vec2::new(0.0, 0.74),
            ],
            "bishop" => vec![
                Vec2::new(0.15, 0.2),
                Vec2::new(0.1, 0.55),
                Vec2::new(0.17, 0.6),
                Vec2::new(0.1, 0.64),
                Vec2::new(0.15, 0.75),
                Vec2::new(0.1, 0.9),
                Vec2::new(0.03, 0.95),
                Vec2::new(0.05, 0.98),
                Vec2::new(0.0, 1.01),
            ],
            "queen" => vec![
                Vec2::new(0.17, 0.2),
                Vec2::new(0.1, 0.7),
                Vec2::new(0.19, 0.76),
                Vec2::new(0.11, 0.8),
                Vec2::new(0.2, 1.0),
                Vec2::new(0.08, 1.0),
                Vec2::new(0.06, 1.06),
                Vec2::new(0.0, 1.1),
            ],
            "king" => vec![
                Vec2::new(0.17, 0.2),
                Vec2::new(0.11, 0.75),
                Vec2::new(0.2, 0.8),
                Vec2::new(0.12, 0.84),
                Vec2::new(0.17, 1.0),
                Vec2::new(0.05, 1.04),
                Vec2::new(0.05, 1.14),
                Vec2::new(0.0, 1.16),
            ],
            _ => return None,
        };
        let profile: Vec<Vec2> = base.iter().copied().chain(top).collect();
        Some(Self::revolve(kind, &profile, segments))
    }

    /// An icosphere of radius `r` (`subdiv` = 0 gives 12 vertices, 1 gives 42, 2 gives 162),
    /// closed, smooth normals. Useful as a coarse model for per-vertex techniques.
    pub fn icosphere(r: f32, subdiv: u32) -> Self {
        use std::collections::HashMap;
        let t = (1.0 + 5.0f32.sqrt()) / 2.0;
        let mut p: Vec<Vec3> = [
            (-1.0, t, 0.0),
            (1.0, t, 0.0),
            (-1.0, -t, 0.0),
            (1.0, -t, 0.0),
            (0.0, -1.0, t),
            (0.0, 1.0, t),
            (0.0, -1.0, -t),
            (0.0, 1.0, -t),
            (t, 0.0, -1.0),
            (t, 0.0, 1.0),
            (-t, 0.0, -1.0),
            (-t, 0.0, 1.0),
        ]
        .iter()
        .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
        .collect();
        let mut f: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..subdiv.min(5) {
            let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
            let mut nf = Vec::with_capacity(f.len() * 4);
            let mut get = |a: u32, b: u32, p: &mut Vec<Vec3>| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    p.push(((p[a as usize] + p[b as usize]) * 0.5).normalize());
                    p.len() as u32 - 1
                })
            };
            for [a, b, c] in f {
                let ab = get(a, b, &mut p);
                let bc = get(b, c, &mut p);
                let ca = get(c, a, &mut p);
                nf.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            f = nf;
        }
        let uvs = p
            .iter()
            .map(|d| {
                let (u, v) = crate::Environment::uv(*d);
                Vec2::new(u, v)
            })
            .collect();
        MeshData {
            name: "icosphere".into(),
            normals: p.clone(),
            positions: p.iter().map(|v| *v * r).collect(),
            uvs,
            indices: f.into_iter().flatten().collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every triangle's geometric normal agrees with its vertex normals (CCW from outside).
    fn check_winding(m: &MeshData) {
        for t in m.indices.chunks(3) {
            let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
            let g = (m.positions[b] - m.positions[a]).cross(m.positions[c] - m.positions[a]);
            if g.length() < 1e-9 {
                continue;
            }
            let n = m.normals[a] + m.normals[b] + m.normals[c];
            assert!(g.dot(n) > 0.0, "{}: triangle {:?} winds clockwise", m.name, t);
        }
    }

    fn area(m: &MeshData) -> f32 {
        m.indices
            .chunks(3)
            .map(|t| {
                let p = |i: u32| m.positions[i as usize];
                0.5 * (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0])).length()
            })
            .sum()
    }

    #[test]
    fn refine_long_edges_is_conforming_and_keeps_the_surface() {
        // a 2-triangle floor: every edge ends up at most the limit, area and winding kept
        let floor = MeshData::plane(6.0, 1);
        let r = floor.refine_long_edges(0.5, 1 << 20);
        assert!(r.triangle_count() > 200, "{}", r.triangle_count());
        for t in r.indices.chunks(3) {
            for k in 0..3 {
                let l = (r.positions[t[k] as usize] - r.positions[t[(k + 1) % 3] as usize]).length();
                assert!(l <= 0.5 + 1e-5, "edge {l}");
            }
        }
        assert!((area(&r) - 36.0).abs() < 1e-3, "{}", area(&r));
        check_winding(&r);
        assert_eq!(r.positions.len(), r.uvs.len());
        // uvs interpolate linearly on a plane: uv = (x, z) + 3
        for (p, uv) in r.positions.iter().zip(&r.uvs) {
            assert!((uv.x - (p.x + 3.0)).abs() < 1e-4 && (uv.y - (p.z + 3.0)).abs() < 1e-4, "{p} {uv}");
        }
        // a closed mesh with uv seams and poles stays closed (no T-junctions), mixed triangle sizes
        let s = MeshData::uv_sphere(1.0, 12, 6);
        assert!(s.is_closed());
        let r = s.refine_long_edges(0.3, 1 << 20);
        assert!(r.triangle_count() > 4 * s.triangle_count());
        assert!(r.is_closed(), "refined sphere has open edges");
        check_winding(&r);
        // the cap stops before a pass that would exceed it; nothing to do leaves the mesh as it is
        let capped = floor.refine_long_edges(0.01, 100);
        assert!(capped.triangle_count() <= 100 && capped.triangle_count() > 2, "{}", capped.triangle_count());
        assert_eq!(floor.refine_long_edges(100.0, 1 << 20).indices, floor.indices);
        assert_eq!(floor.refine_long_edges(0.0, 1 << 20).indices, floor.indices);
    }

    #[test]
    fn primitives_wind_counter_clockwise() {
        for m in [
            MeshData::plane(2.0, 3),
            MeshData::uv_sphere(1.0, 12, 6),
            MeshData::cube(1.0),
            MeshData::torus(1.0, 0.3, 12, 8),
        ] {
            assert!(m.triangle_count() > 0);
            assert_eq!(m.positions.len(), m.normals.len());
            assert_eq!(m.positions.len(), m.uvs.len());
            assert!(m.indices.iter().all(|&i| (i as usize) < m.positions.len()));
            check_winding(&m);
        }
    }

    #[test]
    fn generated_meshes_are_valid_and_closed_where_expected() {
        let mut w = Vec::new();
        let closed = [
            MeshData::hat(0.6, 0.5, 24),
            MeshData::hat_refined(0.6, 0.5, 24, 3),
            MeshData::dish(1.0, 0.2, 32, 4),
            MeshData::icosphere(1.0, 2),
            MeshData::uv_sphere(1.0, 12, 6),
            MeshData::torus(1.0, 0.3, 12, 8),
            MeshData::cube(0.5),
        ];
        for k in ["pawn", "rook", "bishop", "queen", "king"] {
            let m = MeshData::chess_piece(k, 16).unwrap();
            check_winding(&m);
            assert!(m.is_closed(), "{k} not closed: {:?}", m.edge_stats());
        }
        assert!(MeshData::chess_piece("dragon", 16).is_none());
        for mut m in closed {
            check_winding(&m);
            assert!(m.is_closed(), "{} not closed: {:?}", m.name, m.edge_stats());
            m.validate_and_repair("t", &mut w).unwrap();
        }
        assert_eq!(MeshData::icosphere(1.0, 2).positions.len(), 162);
        let cloth = MeshData::cloth(2.0, 1.5, 8, 6, 2.0, 0.2);
        check_winding(&cloth);
        assert!(!cloth.is_closed());
        assert_eq!(cloth.edge_stats().boundary, 2 * (8 + 6));
        assert!(!MeshData::plane(1.0, 1).is_closed());
        assert!(w.is_empty(), "{w:?}");
    }

    #[test]
    fn repair_removes_zero_area_triangles_and_normalizes_normals() {
        let mut m = MeshData::plane(1.0, 1);
        // Append a degenerate triangle (two identical vertices) and scale a normal.
        m.indices.extend_from_slice(&[0, 0, 1]);
        m.normals[2] *= 3.0;
        let mut w = Vec::new();
        m.validate_and_repair("file.glb", &mut w).unwrap();
        assert_eq!(m.triangle_count(), 2);
        assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-6));
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].contains("file.glb") && w[0].contains("zero-area"), "{w:?}");
        assert!(w[1].contains("unnormalized"), "{w:?}");
    }

    #[test]
    fn validation_rejects_bad_meshes() {
        let mut w = Vec::new();
        let mut m = MeshData::plane(1.0, 1);
        m.indices[4] = 99;
        assert!(m.validate_and_repair("x", &mut w).unwrap_err().contains("out of range"));
        let mut m = MeshData::plane(1.0, 1);
        m.positions[1].y = f32::NAN;
        assert!(m.validate_and_repair("x", &mut w).unwrap_err().contains("non-finite"));
        let mut m = MeshData::plane(1.0, 1);
        m.indices.pop();
        assert!(m.validate_and_repair("x", &mut w).unwrap_err().contains("multiple of 3"));
        let mut m = MeshData::default();
        assert!(m.validate_and_repair("x", &mut w).unwrap_err().contains("no triangles"));
    }

    #[test]
    fn non_manifold_edge_detected() {
        // Three triangles sharing one edge.
        let m = MeshData {
            name: "fin".into(),
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z, Vec3::NEG_Y],
            normals: vec![Vec3::Y; 5],
            uvs: vec![Vec2::ZERO; 5],
            indices: vec![0, 1, 2, 0, 1, 3, 1, 0, 4],
        };
        let s = m.edge_stats();
        assert_eq!(s.non_manifold, 1);
        assert!(!m.is_closed());
    }
}
