//! `penumbra spheres`: approximate a closed mesh by N spheres (the ISG technique's blockers).

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra_math::sphereset::{approximate_spheres, measure_coverage};
use penumbra_scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct SpheresArgs {
    /// A glTF model (.glb/.gltf) or a scene file (.toml).
    pub mesh: PathBuf,
    /// Number of spheres.
    #[arg(long, default_value_t = 32)]
    pub count: usize,
    /// Output sphere file (text format `penumbra-spheres 1 N`, see `penumbra_math::sphereset`).
    #[arg(long)]
    pub out: PathBuf,
    /// The object to approximate (default: the first object with a closed mesh).
    #[arg(long)]
    pub object: Option<String>,
    /// Voxel resolution (along the longest axis) of the coverage measurement.
    #[arg(long, default_value_t = 96)]
    pub coverage_resolution: usize,
}

/// Approximates the chosen object and writes the sphere file.
pub fn run(args: &SpheresArgs, scene: &Scene) -> Result<()> {
    let file = args.mesh.display();
    let object = match &args.object {
        Some(name) => scene
            .objects
            .iter()
            .find(|o| &o.name == name)
            .with_context(|| format!("{file}: no object named '{name}'"))?,
        None => scene
            .objects
            .iter()
            .find(|o| scene.meshes.get(o.mesh).is_some_and(|m| m.is_closed()))
            .with_context(|| format!("{file}: no object has a closed mesh (sphere sets approximate solids)"))?,
    };
    let mesh =
        scene.meshes.get(object.mesh).with_context(|| format!("{file}: object '{}' has no mesh", object.name))?;
    if !mesh.is_closed() {
        let e = mesh.edge_stats();
        anyhow::bail!(
            "{file}: object '{}' is not a closed mesh ({} boundary edges, {} non-manifold edges); sphere sets need solids",
            object.name,
            e.boundary,
            e.non_manifold
        );
    }
    if args.count == 0 {
        anyhow::bail!("--count must be at least 1");
    }
    let set = approximate_spheres(&mesh.positions, &mesh.indices, args.count)
        .map_err(|e| anyhow::anyhow!("{file}: object '{}': {e}", object.name))?;
    let cov = measure_coverage(&mesh.positions, &mesh.indices, &set.spheres, args.coverage_resolution)
        .map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    std::fs::write(&args.out, set.to_text()).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "{} spheres for '{}' ({} vertices): {:.1}% of the mesh volume covered, {:.2}% of it outside the mesh; wrote {}",
        set.spheres.len(),
        object.name,
        mesh.positions.len(),
        cov.covered * 100.0,
        cov.outside * 100.0,
        args.out.display()
    );
    Ok(())
}
