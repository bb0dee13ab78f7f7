//! CPU preview of a scene (no GPU): a z-buffered flat-shaded rasterization of the frame at a
//! time, written as PNG. `cargo run -p penumbra-scene --example preview -- SCENE [t] [out.png]`.

use glam::{Vec3, Vec4Swizzles};
use penumbra_scene::Scene;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: preview SCENE [t] [out.png]");
    let t: f32 = args.get(2).map_or(0.0, |s| s.parse().unwrap());
    let out = args.get(3).cloned().unwrap_or_else(|| "preview.png".into());
    let scene = match Scene::load(path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    let (w, h) = (320usize, 240usize);
    let frame = scene.at(t, None);
    let vp = frame.camera.proj(w as f32 / h as f32) * frame.camera.view();
    let mut depth = vec![f32::INFINITY; w * h];
    let mut img = vec![[30u8, 30, 40]; w * h];
    let light = Vec3::new(0.4, 0.8, 0.5).normalize();
    for inst in &frame.instances {
        let mesh = inst.deformed_mesh.as_deref().unwrap_or(&scene.meshes[inst.mesh]);
        let mat = &frame.materials[inst.material];
        let extra = scene.material_extra(inst.material);
        let wp: Vec<Vec3> = mesh.positions.iter().map(|p| inst.world.transform_point3(*p)).collect();
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
            let n = (wp[b] - wp[a]).cross(wp[c] - wp[a]).normalize_or_zero();
            let mut albedo = mat.albedo + mat.specular * 0.5;
            if let Some(ti) = extra.albedo_map {
                let uv = (mesh.uvs[a] + mesh.uvs[b] + mesh.uvs[c]) / 3.0;
                albedo *= scene.textures[ti].sample(uv).xyz();
            }
            let shade = albedo * (0.25 + 0.75 * n.dot(light).abs());
            let col = shade.powf(1.0 / 2.2).clamp(Vec3::ZERO, Vec3::ONE) * 255.0;
            let clip: Vec<glam::Vec4> = [a, b, c].iter().map(|&i| vp * wp[i].extend(1.0)).collect();
            if clip.iter().any(|c| c.w <= 1e-4) {
                continue;
            }
            let s: Vec<Vec3> = clip
                .iter()
                .map(|c| Vec3::new((c.x / c.w * 0.5 + 0.5) * w as f32, (c.y / c.w * 0.5 + 0.5) * h as f32, c.z / c.w))
                .collect();
            let lo = s[0].min(s[1]).min(s[2]);
            let hi = s[0].max(s[1]).max(s[2]);
            let area = (s[1].x - s[0].x) * (s[2].y - s[0].y) - (s[2].x - s[0].x) * (s[1].y - s[0].y);
            if area.abs() < 1e-9 {
                continue;
            }
            for y in (lo.y.max(0.0) as usize)..(hi.y.min(h as f32 - 1.0).max(0.0) as usize + 1) {
                for x in (lo.x.max(0.0) as usize)..(hi.x.min(w as f32 - 1.0).max(0.0) as usize + 1) {
                    let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = ((s[1].x - px) * (s[2].y - py) - (s[2].x - px) * (s[1].y - py)) / area;
                    let w1 = ((s[2].x - px) * (s[0].y - py) - (s[0].x - px) * (s[2].y - py)) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = w0 * s[0].z + w1 * s[1].z + w2 * s[2].z;
                    if z < depth[y * w + x] {
                        depth[y * w + x] = z;
                        img[y * w + x] = [col.x as u8, col.y as u8, col.z as u8];
                    }
                }
            }
        }
    }
    let buf: Vec<u8> = img.into_iter().flatten().collect();
    image::save_buffer(&out, &buf, w as u32, h as u32, image::ExtendedColorType::Rgb8).unwrap();
    println!("{}: {} objects, {} vertices -> {out}", scene.name, scene.objects.len(), scene.vertex_count());
}
