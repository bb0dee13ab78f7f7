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
}
