//! CPU parts of the volumetric effect: adjacency for the silhouette geometry shader.

use penumbra_passes::volumetric::{adjacency_indices, VolumetricMethod};
use penumbra_scene::MeshData;

#[test]
fn closed_meshes_have_full_adjacency_open_ones_fall_back() {
    for m in [MeshData::icosphere(1.0, 2), MeshData::cube(1.0), MeshData::torus(1.0, 0.3, 16, 8)] {
        let (idx, open) = adjacency_indices(&m);
        assert_eq!(open, 0, "{}", m.name);
        assert_eq!(idx.len(), m.indices.len() * 2);
        // Each triangle's own vertices are at even positions, in order.
        for (t, tri) in m.indices.chunks_exact(3).enumerate() {
            assert_eq!([idx[6 * t], idx[6 * t + 2], idx[6 * t + 4]], [tri[0], tri[1], tri[2]]);
            // The adjacent vertex is never one of the edge's own (welded) vertices.
            let ids = m.weld_ids();
            for k in 0..3 {
                let adj = ids[idx[6 * t + 2 * k + 1] as usize];
                let (a, b) = (ids[tri[k] as usize], ids[tri[(k + 1) % 3] as usize]);
                assert!(adj != a && adj != b, "{}: triangle {t} edge {k}", m.name);
            }
        }
    }
    // A plane: its border edges fall back to the triangle's own opposite vertex.
    let p = MeshData::plane(1.0, 2);
    let (idx, open) = adjacency_indices(&p);
    assert_eq!(open, p.edge_stats().boundary);
    assert!(open > 0);
    assert_eq!(idx.len(), p.indices.len() * 2);
}

#[test]
fn method_names() {
    assert_eq!(VolumetricMethod::parse("full").unwrap(), VolumetricMethod::Full);
    assert_eq!(VolumetricMethod::parse("temporal").unwrap(), VolumetricMethod::Temporal);
    assert!(VolumetricMethod::parse("Temporal").is_err());
}
