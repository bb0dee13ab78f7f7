//! Bounds on what loading a scene may allocate, checked from file sizes, image headers and
//! glTF accessor counts before anything is allocated: a hostile or corrupt file gets an error
//! naming it, never an allocation that aborts the process or exhausts the machine.

use crate::error::SceneError;
use std::cell::Cell;
use std::path::Path;

const MIB: u64 = 1 << 20;

/// What a scene may cost to load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Host bytes the scene's meshes, textures and environment map may take, summed over every
    /// file it loads (estimated before reading: accessor counts, image headers). Default 1 GiB;
    /// the CLI raises it with `--memory-budget MIB`.
    pub memory_bytes: u64,
    /// Largest width or height of a texture or environment map (GPU upload limits are checked
    /// again against the device).
    pub max_image_dim: u32,
    /// Largest scene file (.toml).
    pub max_scene_file_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { memory_bytes: 1024 * MIB, max_image_dim: 16384, max_scene_file_bytes: 16 * MIB }
    }
}

impl Limits {
    /// These limits with a memory budget of `mib` MiB.
    pub fn with_memory_mib(mib: u64) -> Self {
        Limits { memory_bytes: mib.saturating_mul(MIB), ..Default::default() }
    }
}

/// The memory budget of one scene load: each file's estimate is taken from it before the file's
/// data is allocated.
#[derive(Debug)]
pub struct Budget {
    pub limits: Limits,
    used: Cell<u64>,
}

fn mib(b: u64) -> String {
    if b >= 10 * MIB {
        format!("{} MiB", b / MIB)
    } else {
        format!("{:.1} MiB", b as f64 / MIB as f64)
    }
}

impl Budget {
    pub fn new(limits: Limits) -> Self {
        Budget { limits, used: Cell::new(0) }
    }

    /// Bytes taken so far.
    pub fn used(&self) -> u64 {
        self.used.get()
    }

    /// Takes `bytes` for `what` in `path`, or fails naming both and the budget.
    pub fn take(&self, path: &Path, what: &str, bytes: u64) -> Result<(), SceneError> {
        let total = self.used.get().saturating_add(bytes);
        if total > self.limits.memory_bytes {
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                message: format!(
                    "{what} needs {} of memory, over the scene's budget of {} ({} already taken by the scene); raise it with --memory-budget MIB",
                    mib(bytes),
                    mib(self.limits.memory_bytes),
                    mib(self.used.get())
                ),
            });
        }
        self.used.set(total);
        Ok(())
    }

    /// Checks an image's dimensions (from its header) and takes `bytes_per_texel` per texel.
    pub fn image(
        &self,
        path: &Path,
        what: &str,
        width: u64,
        height: u64,
        bytes_per_texel: u64,
    ) -> Result<(), SceneError> {
        let max = self.limits.max_image_dim as u64;
        if width == 0 || height == 0 {
            return Err(SceneError::invalid(path, format!("{what} is empty ({width}x{height})")));
        }
        if width > max || height > max {
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                message: format!("{what} is {width}x{height}, over the largest accepted side of {max} texels"),
            });
        }
        self.take(
            path,
            &format!("{what} ({width}x{height})"),
            width.saturating_mul(height).saturating_mul(bytes_per_texel),
        )
    }

    /// Reads a whole file whose size is at most `max` bytes (and within the budget).
    pub fn read_file(&self, path: &Path, what: &str, max: u64) -> Result<Vec<u8>, SceneError> {
        let len = std::fs::metadata(path).map_err(|e| SceneError::io(path, e))?.len();
        if len > max {
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                message: format!("the {what} is {}, over the largest accepted {}", mib(len), mib(max)),
            });
        }
        self.take(path, &format!("the {what}"), len)?;
        crate::error::read_file(path)
    }

    /// Reads a file the budget bounds (models, images), taking its size from the budget.
    pub fn read_data_file(&self, path: &Path, what: &str) -> Result<Vec<u8>, SceneError> {
        let len = std::fs::metadata(path).map_err(|e| SceneError::io(path, e))?.len();
        self.take(path, &format!("the {what} ({len} bytes)"), len)?;
        crate::error::read_file(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_budget_is_shared_by_every_file_and_names_the_culprit() {
        let b = Budget::new(Limits::with_memory_mib(10));
        let p = Path::new("a.glb");
        b.take(p, "positions", 6 * MIB).unwrap();
        let e = b.take(Path::new("b.exr"), "the environment", 5 * MIB).unwrap_err().to_string();
        assert!(
            e.starts_with("b.exr:")
                && e.contains("the environment")
                && e.contains("budget of 10 MiB")
                && e.contains("--memory-budget"),
            "{e}"
        );
        assert_eq!(b.used(), 6 * MIB);
        let e = b.image(p, "image 0", 100_000, 100_000, 16).unwrap_err().to_string();
        assert!(e.contains("100000x100000") && e.contains("16384"), "{e}");
        assert!(b.image(p, "image 1", 0, 4, 16).is_err());
        assert!(b.take(p, "huge", u64::MAX).is_err());
    }
}
