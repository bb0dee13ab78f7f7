//! The library's error, by kind: an embedding application (and the CLI's exit codes) can tell
//! bad input (a scene file, a technique name or parameter, an image size) from a device that ran
//! out of memory or was lost, without reading messages.

use penumbra_engine::vk;
use std::path::{Path, PathBuf};

/// What kind of failure an [`Error`] is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// The input is wrong (fix the scene file or the settings); nothing is wrong with the device.
    BadInput,
    /// Host or device memory ran out (try a smaller image or scene, or fewer frames in flight).
    OutOfMemory,
    /// The device was lost (driver reset, hang): the renderer cannot continue.
    DeviceLost,
    /// Anything else (a driver or I/O failure, a bug).
    Other,
}

/// An error of the [`Renderer`](crate::Renderer) API.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad input, with the scene file it came from when known.
    #[error("{}{message}", file.as_deref().map(|f| format!("{}: ", f.display())).unwrap_or_default())]
    BadInput { file: Option<PathBuf>, message: String },
    #[error("out of memory: {0:#}")]
    OutOfMemory(anyhow::Error),
    #[error("the device was lost: {0:#}")]
    DeviceLost(anyhow::Error),
    #[error("{0:#}")]
    Other(anyhow::Error),
}

impl Error {
    pub fn kind(&self) -> ErrorKind {
        match self {
            Error::BadInput { .. } => ErrorKind::BadInput,
            Error::OutOfMemory(_) => ErrorKind::OutOfMemory,
            Error::DeviceLost(_) => ErrorKind::DeviceLost,
            Error::Other(_) => ErrorKind::Other,
        }
    }

    pub(crate) fn bad_input(file: Option<&Path>, message: impl Into<String>) -> Self {
        Error::BadInput { file: file.map(Path::to_path_buf), message: message.into() }
    }

    /// Sorts an internal error by what its chain contains: a bad-input error of the passes (a
    /// technique name or parameter) or of the scene loader, an out-of-memory or device-lost
    /// Vulkan result (or allocator failure). `file` is the scene file, for bad input.
    pub(crate) fn classify(e: anyhow::Error, file: Option<&Path>) -> Self {
        for cause in e.chain() {
            if cause.downcast_ref::<penumbra_passes::registry::BadInput>().is_some()
                || cause.downcast_ref::<penumbra_scene::SceneError>().is_some()
            {
                return Error::bad_input(file, format!("{e:#}"));
            }
            if let Some(r) = cause.downcast_ref::<vk::Result>() {
                match *r {
                    vk::Result::ERROR_OUT_OF_HOST_MEMORY
                    | vk::Result::ERROR_OUT_OF_DEVICE_MEMORY
                    | vk::Result::ERROR_OUT_OF_POOL_MEMORY => return Error::OutOfMemory(e),
                    vk::Result::ERROR_DEVICE_LOST => return Error::DeviceLost(e),
                    _ => {}
                }
            }
            if let Some(gpu_allocator::AllocationError::OutOfMemory) =
                cause.downcast_ref::<gpu_allocator::AllocationError>()
            {
                return Error::OutOfMemory(e);
            }
        }
        Error::Other(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_sorted_by_kind() {
        let bad =
            anyhow::Error::new(penumbra_passes::registry::BadInput("unknown technique 'x'".into())).context("creating");
        let e = Error::classify(bad, Some(Path::new("scenes/a.toml")));
        assert_eq!(e.kind(), ErrorKind::BadInput);
        assert!(e.to_string().starts_with("scenes/a.toml: creating"), "{e}");
        let oom = anyhow::Error::new(vk::Result::ERROR_OUT_OF_DEVICE_MEMORY).context("allocating the G-buffer");
        assert_eq!(Error::classify(oom, None).kind(), ErrorKind::OutOfMemory);
        let lost = anyhow::Error::new(vk::Result::ERROR_DEVICE_LOST).context("waiting for frame 3");
        let e = Error::classify(lost, None);
        assert_eq!(e.kind(), ErrorKind::DeviceLost);
        assert!(e.to_string().contains("waiting for frame 3"), "{e}");
        assert_eq!(Error::classify(anyhow::anyhow!("disk full"), None).kind(), ErrorKind::Other);
    }
}
