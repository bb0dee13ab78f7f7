//! `render --renderdoc-capture N`: one frame captured through RenderDoc's in-application API
//! (the `renderdoc` crate), for headless runs where RenderDoc's own capture key has no window
//! to watch. RenderDoc must already be loaded in the process (penumbra launched by
//! `renderdoccmd capture` or from qrenderdoc): its Vulkan layer has to be in place before the
//! instance is created, so the library is looked up, never loaded here.

use anyhow::Result;
use renderdoc::{RenderDoc, V110};

/// The capture of one frame of a `render` run.
pub struct FrameCapture {
    rd: RenderDoc<V110>,
    /// The frame captured (0-based, as `frame_NNNN` files count).
    pub frame: u32,
}

impl FrameCapture {
    /// For `--renderdoc-capture frame` of a run of `frames` frames: bad input when the frame is
    /// past the run or RenderDoc is not loaded (saying how to run under it).
    pub fn new(frame: u32, frames: u32) -> Result<FrameCapture> {
        if frame >= frames {
            return Err(crate::bad(format!(
                "--renderdoc-capture {frame} is past the last frame ({} with --frames {frames})",
                frames - 1
            )));
        }
        let rd = RenderDoc::<V110>::new().map_err(|e| {
            crate::bad(format!(
                "--renderdoc-capture: RenderDoc is not loaded in this process ({e}); run penumbra under it, e.g. \
                 `renderdoccmd capture -w penumbra render ... --renderdoc-capture {frame}`, or launch it from qrenderdoc"
            ))
        })?;
        Ok(FrameCapture { rd, frame })
    }

    /// Runs `f` (frame `k`'s build and submission) inside a capture when `k` is the frame asked
    /// for; prints where RenderDoc wrote it.
    pub fn around<T>(&mut self, k: u32, f: impl FnOnce() -> Result<T>) -> Result<T> {
        if k != self.frame {
            return f();
        }
        // null device and window: RenderDoc's wildcard (penumbra has one device, no window)
        self.rd.start_frame_capture(std::ptr::null(), std::ptr::null());
        let r = f();
        self.rd.end_frame_capture(std::ptr::null(), std::ptr::null());
        let n = self.rd.get_num_captures();
        match n.checked_sub(1).and_then(|i| self.rd.get_capture(i)) {
            Some((path, _)) => println!("RenderDoc captured frame {k}: {}", path.display()),
            None => eprintln!("warning: RenderDoc reported no capture for frame {k}"),
        }
        r
    }
}
