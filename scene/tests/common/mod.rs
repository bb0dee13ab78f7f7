//! Test helpers: a tiny glTF writer (JSON + binary buffer) and temp directories.
#![allow(dead_code)]

use serde_json::{json, Value};
use std::path::PathBuf;

/// A fresh temporary directory for one test (under cargo's target/tmp, not the system temp dir).
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("penumbra-scene-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Accumulates buffer views and accessors over one binary buffer.
#[derive(Default)]
pub struct Bin {
    pub bytes: Vec<u8>,
    pub views: Vec<Value>,
    pub accessors: Vec<Value>,
}

impl Bin {
    fn view(&mut self, data: &[u8]) -> usize {
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        let off = self.bytes.len();
        self.bytes.extend_from_slice(data);
        self.views.push(json!({"buffer": 0, "byteOffset": off, "byteLength": data.len()}));
        self.views.len() - 1
    }

    /// A float accessor of `ty` ("SCALAR", "VEC3", "VEC4", "MAT4") over `data`.
    pub fn f32s(&mut self, data: &[f32], ty: &str) -> usize {
        let n = match ty {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            "MAT4" => 16,
            _ => panic!(),
        };
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let v = self.view(&bytes);
        let mut acc = json!({"bufferView": v, "componentType": 5126, "count": data.len() / n, "type": ty});
        if ty == "VEC3" {
            let mut lo = [f32::MAX; 3];
            let mut hi = [f32::MIN; 3];
            for c in data.chunks(3) {
                for k in 0..3 {
                    lo[k] = lo[k].min(c[k]);
                    hi[k] = hi[k].max(c[k]);
                }
            }
            if lo.iter().chain(hi.iter()).all(|x| x.is_finite()) {
                acc["min"] = json!(lo);
                acc["max"] = json!(hi);
            }
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }

    pub fn u32s(&mut self, data: &[u32]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let v = self.view(&bytes);
        self.accessors.push(json!({"bufferView": v, "componentType": 5125, "count": data.len(), "type": "SCALAR"}));
        self.accessors.len() - 1
    }

    pub fn u16x4(&mut self, data: &[[u16; 4]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
        let v = self.view(&bytes);
        self.accessors.push(json!({"bufferView": v, "componentType": 5123, "count": data.len(), "type": "VEC4"}));
        self.accessors.len() - 1
    }

    /// Finish: a complete glTF JSON with `rest` merged in (meshes, nodes, ...), the buffer
    /// given by `uri` (None = GLB binary chunk).
    pub fn document(&self, uri: Option<String>, mut rest: Value) -> Value {
        let mut buffer = json!({"byteLength": self.bytes.len()});
        if let Some(u) = uri {
            buffer["uri"] = json!(u);
        }
        rest["asset"] = json!({"version": "2.0"});
        rest["buffers"] = json!([buffer]);
        rest["bufferViews"] = json!(self.views);
        rest["accessors"] = json!(self.accessors);
        rest
    }

    /// The buffer as a base64 data URI.
    pub fn data_uri(&self) -> String {
        format!("data:application/octet-stream;base64,{}", base64(&self.bytes))
    }
}

pub fn base64(data: &[u8]) -> String {
    const T: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in data.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(T[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Gives `doc` one texture (index 0): a 1x1 white PNG embedded as a data URI.
pub fn white_texture(doc: &mut Value) {
    let mut png = Vec::new();
    image::RgbImage::from_pixel(1, 1, image::Rgb([255, 255, 255]))
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64(&png))}]);
    doc["textures"] = json!([{"source": 0}]);
}

/// A binary glTF container.
pub fn glb(json: &Value, bin: &[u8]) -> Vec<u8> {
    penumbra_scene::gltf_load::glb_bytes(&serde_json::to_vec(json).unwrap(), bin)
}

/// A unit tetrahedron (closed) as positions + indices.
pub fn tetra() -> (Vec<f32>, Vec<u32>) {
    (vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3])
}

/// A document with one mesh node (tetrahedron unless overridden) and one material.
pub fn simple(bin: &mut Bin, positions: &[f32], indices: &[u32], uri: Option<String>) -> Value {
    let p = bin.f32s(positions, "VEC3");
    let i = bin.u32s(indices);
    bin.document(
        uri,
        json!({
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "translation": [0.0, 1.0, 0.0]}],
            "meshes": [{"name": "tet", "primitives": [{"attributes": {"POSITION": p}, "indices": i, "material": 0}]}],
            "materials": [{"name": "metal", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.6, 0.2, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.3}}],
        }),
    )
}
