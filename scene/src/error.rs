//! The one error type of the crate. Every message starts with the file it is about.

use std::path::{Path, PathBuf};

/// Anything that can go wrong loading or checking a scene. `Display` names the file and the
/// problem, e.g. `scenes/x.toml: TOML parse error at line 3, column 1 ...`.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read (missing file, permission, ...).
    #[error("{}: cannot read file: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// Syntax or schema error in a scene file (unknown key, wrong type, missing key); the
    /// message contains line and column.
    #[error("{}: {message}", path.display())]
    Syntax { path: PathBuf, message: String },
    /// A glTF file that is truncated, malformed, or references missing data.
    #[error("{}: invalid glTF: {message}", path.display())]
    Gltf { path: PathBuf, message: String },
    /// A valid file that uses a feature this crate does not read (named in `feature`).
    #[error("{}: unsupported {feature}", path.display())]
    Unsupported { path: PathBuf, feature: String },
    /// An image (EXR, HDR, PNG, ...) that cannot be decoded.
    #[error("{}: invalid image: {message}", path.display())]
    Image { path: PathBuf, message: String },
    /// Well-formed input with invalid content: NaN/Inf values, indices out of range, empty
    /// scene, references to unknown names, ...
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// A mesh that must be closed (for the chosen technique) has borders or non-manifold edges.
    /// `path` is the scene file, `mesh_file` the file the mesh came from.
    #[error("{}: object '{object}' (mesh from {}) is not a closed mesh ({boundary} boundary edges, {non_manifold} non-manifold edges); {why}", path.display(), mesh_file.display())]
    NotClosed { path: PathBuf, mesh_file: PathBuf, object: String, boundary: usize, non_manifold: usize, why: String },
    /// An error in a file referenced from a scene file (`path`, at `line`).
    #[error("{}: line {line}: {source}", path.display())]
    Referenced { path: PathBuf, line: usize, source: Box<SceneError> },
    /// A file, image or accessor over the load limits (`limits::Limits`), found before
    /// allocating.
    #[error("{}: too large: {message}", path.display())]
    TooLarge { path: PathBuf, message: String },
    /// The file extension is not one `Scene::load` understands.
    #[error("{}: unknown scene file type (expected .toml, .glb or .gltf)", path.display())]
    UnknownFormat { path: PathBuf },
}

impl SceneError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            SceneError::Io { path, .. }
            | SceneError::Syntax { path, .. }
            | SceneError::Gltf { path, .. }
            | SceneError::Unsupported { path, .. }
            | SceneError::Image { path, .. }
            | SceneError::Invalid { path, .. }
            | SceneError::NotClosed { path, .. }
            | SceneError::Referenced { path, .. }
            | SceneError::TooLarge { path, .. }
            | SceneError::UnknownFormat { path } => path,
        }
    }

    /// The innermost error (through [`SceneError::Referenced`]).
    pub fn root_cause(&self) -> &SceneError {
        match self {
            SceneError::Referenced { source, .. } => source.root_cause(),
            e => e,
        }
    }

    pub(crate) fn invalid(path: &Path, message: impl Into<String>) -> Self {
        SceneError::Invalid { path: path.to_path_buf(), message: message.into() }
    }
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        SceneError::Io { path: path.to_path_buf(), source }
    }
}

/// Read a whole file, mapping failures to [`SceneError::Io`].
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, SceneError> {
    std::fs::read(path).map_err(|e| SceneError::io(path, e))
}
