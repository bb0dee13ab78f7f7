//! The explicit render graph.
//!
//! A frame is built by declaring resources and passes; each pass declares every use of every
//! resource with an [`Access`]. [`Graph::compile`] validates the declarations (reporting all
//! problems at once), culls passes whose results reach no output, and derives the barriers the
//! declarations imply: one `vkCmdPipelineBarrier2` per pass holding all its transitions. The
//! compiled form has no GPU handles, so it is unit-testable without a device and can be dumped
//! deterministically ([`dump`](crate::dump)).
//!
//! Resource handles are versioned: declaring a write returns a new handle; reading an older
//! version after a newer one was written is an error (its contents are gone).

pub use crate::access;
pub mod compile;

pub use crate::resource::{BufferDesc, BufferHandle, GraphHandle, ImageDesc, ImageHandle};
pub use access::{Access, AccessInfo, Applies};
pub use compile::{Barrier, CompiledGraph, CompiledPass, GraphError, Problem, ResourceInfo, ResourceState};

use ash::vk;
use std::fmt;

/// Where a resource comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// Allocated by the graph for this frame from a pool reused across frames.
    Transient,
    /// Owned by the application; the graph knows its usage and state before and after the frame.
    Imported {
        usage: Usage,
        /// The last access before this frame (its layout, and a pending write to wait for).
        /// `None`: contents ready and visible, layout given by `initial_layout`.
        initial: Option<Access>,
        initial_layout: vk::ImageLayout,
        /// The state the resource must be left in after the frame (a graph output).
        final_access: Option<Access>,
    },
    /// Kept by the engine across frames under this key (history images, previous-frame data).
    Persistent { state: Option<ResourceState> },
    /// Transient, host-visible, filled by the host before submission (uniforms, instance data).
    HostInit,
    /// Transient host-visible buffer read back after the frame; always a graph output.
    Readback,
}

/// Usage flags of an imported resource.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Usage {
    Image(vk::ImageUsageFlags),
    Buffer(vk::BufferUsageFlags),
}

#[derive(Clone, Debug, PartialEq)]
pub enum ResourceDesc {
    Image(ImageDesc),
    Buffer(BufferDesc),
}

impl ResourceDesc {
    pub fn is_image(&self) -> bool {
        matches!(self, ResourceDesc::Image(_))
    }
    pub fn bytes(&self) -> u64 {
        match self {
            ResourceDesc::Image(d) => d.bytes(),
            ResourceDesc::Buffer(b) => b.size,
        }
    }
}

/// A resource node.
#[derive(Clone, Debug)]
pub struct ResourceNode {
    pub name: String,
    pub desc: ResourceDesc,
    pub origin: Origin,
    /// Latest version declared so far (0 = initial contents).
    pub version: u32,
    /// Explicitly marked as a graph output (kept alive by culling).
    pub output: bool,
    /// Host data for `HostInit` buffers.
    pub init_data: Option<Vec<u8>>,
    /// Vulkan handles of an imported resource.
    pub external: External,
}

/// Vulkan handles of an imported resource.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum External {
    None,
    Image(vk::Image, vk::ImageView),
    Buffer(vk::Buffer),
}

/// An application-owned image handed to the graph.
#[derive(Clone, Debug)]
pub struct ImportedImage {
    pub image: vk::Image,
    pub view: vk::ImageView,
    pub desc: ImageDesc,
    pub usage: vk::ImageUsageFlags,
    /// Its last access before this frame (layout, and a pending write to wait for);
    /// `None`: no pending write, layout `initial_layout`.
    pub initial: Option<Access>,
    pub initial_layout: vk::ImageLayout,
    /// Leave it in this access's state after the frame (makes it a graph output).
    pub final_access: Option<Access>,
}

/// Kind of work a pass records (for dumps and queue capability checks).
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub enum PassKind {
    Raster,
    Compute,
    Transfer,
}

/// One declared use of a resource by a pass.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Use {
    pub resource: u32,
    /// Version read (for reads and read-modify-writes).
    pub read_version: Option<u32>,
    /// Version produced (for writes).
    pub write_version: Option<u32>,
    pub access: Access,
}

/// Records a pass's commands. Returns an error instead of panicking (e.g. a handle the pass did
/// not declare); the executor reports every pass's errors together and does not submit.
pub type RecordFn = Box<dyn FnOnce(&mut crate::record::RecordContext) -> anyhow::Result<()>>;

pub struct PassNode {
    pub name: String,
    pub kind: PassKind,
    pub uses: Vec<Use>,
    /// Runs even if nothing reads its results (e.g. writes to host memory, debug output).
    pub side_effect: bool,
    pub record: Option<RecordFn>,
}

impl fmt::Debug for PassNode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PassNode")
            .field("name", &self.name)
            .field("kind", &self.kind)
            .field("uses", &self.uses)
            .finish()
    }
}

/// Name prefix of late readbacks ([`Graph::create_late_readback`]).
pub const LATE_READBACK_PREFIX: &str = "late:";

/// A frame's graph under construction.
#[derive(Default, Debug)]
pub struct Graph {
    pub(crate) resources: Vec<ResourceNode>,
    pub(crate) passes: Vec<PassNode>,
    /// Problems found while declaring (reported with the compile problems).
    pub(crate) declare_problems: Vec<Problem>,
}

impl Graph {
    pub fn new() -> Self {
        Self::default()
    }

    fn add_resource(&mut self, name: &str, desc: ResourceDesc, origin: Origin) -> u32 {
        if self.resources.iter().any(|r| r.name == name) {
            self.declare_problems.push(Problem::DuplicateResource { resource: name.to_string() });
        }
        self.resources.push(ResourceNode {
            name: name.to_string(),
            desc,
            origin,
            version: 0,
            output: false,
            init_data: None,
            external: External::None,
        });
        (self.resources.len() - 1) as u32
    }

    /// A transient image, allocated from the pool for this frame. Its usage flags are the union
    /// of the usages its declared accesses need.
    pub fn create_image(&mut self, name: &str, desc: ImageDesc) -> ImageHandle {
        ImageHandle { id: self.add_resource(name, ResourceDesc::Image(desc), Origin::Transient), version: 0 }
    }

    /// A transient device buffer.
    pub fn create_buffer(&mut self, name: &str, size: u64) -> BufferHandle {
        let desc = ResourceDesc::Buffer(BufferDesc { size, host_visible: false });
        BufferHandle { id: self.add_resource(name, desc, Origin::Transient), version: 0 }
    }

    /// A transient host-visible buffer filled with `data` before the frame is submitted
    /// (queue submission makes host writes visible, so no barrier is needed for it).
    pub fn create_buffer_init(&mut self, name: &str, data: Vec<u8>) -> BufferHandle {
        let desc = ResourceDesc::Buffer(BufferDesc { size: data.len().max(4) as u64, host_visible: true });
        let id = self.add_resource(name, desc, Origin::HostInit);
        self.resources[id as usize].init_data = Some(data);
        // Version 1: written by the host.
        self.resources[id as usize].version = 1;
        BufferHandle { id, version: 1 }
    }

    /// A host-visible buffer whose contents are returned by the engine after the frame.
    /// It is a graph output.
    pub fn create_readback(&mut self, name: &str, size: u64) -> BufferHandle {
        let desc = ResourceDesc::Buffer(BufferDesc { size, host_visible: true });
        let id = self.add_resource(name, desc, Origin::Readback);
        self.resources[id as usize].output = true;
        BufferHandle { id, version: 0 }
    }

    /// A readback whose contents the engine keeps instead of returning them with the frame's
    /// output: the frames built after this one read the newest finished copy with
    /// `Engine::late_readback(name)` (never waiting), e.g. flags or statistics a technique feeds
    /// back into its next frames. Named `late:<name>` in the graph.
    pub fn create_late_readback(&mut self, name: &str, size: u64) -> BufferHandle {
        self.create_readback(&format!("{LATE_READBACK_PREFIX}{name}"), size)
    }

    /// A persistent image kept by the engine across frames under `name`. Version 0 holds the
    /// previous frame's contents (undefined on the first frame: see [`Graph::persistent_is_new`]).
    pub fn persistent_image(&mut self, name: &str, desc: ImageDesc, state: Option<ResourceState>) -> ImageHandle {
        let id = self.add_resource(name, ResourceDesc::Image(desc), Origin::Persistent { state });
        ImageHandle { id, version: 0 }
    }

    /// A persistent buffer kept across frames.
    pub fn persistent_buffer(&mut self, name: &str, size: u64, state: Option<ResourceState>) -> BufferHandle {
        let desc = ResourceDesc::Buffer(BufferDesc { size, host_visible: false });
        BufferHandle { id: self.add_resource(name, desc, Origin::Persistent { state }), version: 0 }
    }

    /// True when a persistent resource has no contents from a previous frame.
    pub fn persistent_is_new(&self, h: impl GraphHandle) -> bool {
        matches!(self.resources[h.raw().0 as usize].origin, Origin::Persistent { state: None })
    }

    /// An application-owned image (see [`ImportedImage`]). With a `final_access` it is a graph
    /// output, left in that access's layout with its writes visible to that access.
    pub fn import_image(&mut self, name: &str, imp: ImportedImage) -> ImageHandle {
        let origin = Origin::Imported {
            usage: Usage::Image(imp.usage),
            initial: imp.initial,
            initial_layout: imp.initial_layout,
            final_access: imp.final_access,
        };
        let id = self.add_resource(name, ResourceDesc::Image(imp.desc), origin);
        let r = &mut self.resources[id as usize];
        r.output = imp.final_access.is_some();
        r.external = External::Image(imp.image, imp.view);
        ImageHandle { id, version: 0 }
    }

    /// An application-owned buffer whose contents are ready and visible (e.g. uploaded meshes).
    pub fn import_buffer(
        &mut self,
        name: &str,
        buffer: vk::Buffer,
        size: u64,
        usage: vk::BufferUsageFlags,
    ) -> BufferHandle {
        let origin = Origin::Imported {
            usage: Usage::Buffer(usage),
            initial: None,
            initial_layout: vk::ImageLayout::UNDEFINED,
            final_access: None,
        };
        let desc = ResourceDesc::Buffer(BufferDesc { size, host_visible: false });
        let id = self.add_resource(name, desc, origin);
        self.resources[id as usize].external = External::Buffer(buffer);
        BufferHandle { id, version: 0 }
    }

    /// Marks the current contents of a resource as a graph output: the passes producing it are
    /// never culled.
    pub fn mark_output(&mut self, h: impl GraphHandle) {
        if let Some(r) = self.resources.get_mut(h.raw().0 as usize) {
            r.output = true;
        }
    }

    /// Starts declaring a pass. Finish with [`PassBuilder::record`].
    pub fn pass(&mut self, name: &str, kind: PassKind) -> PassBuilder<'_> {
        if self.passes.iter().any(|p| p.name == name) {
            self.declare_problems.push(Problem::DuplicatePass { pass: name.to_string() });
        }
        self.passes.push(PassNode { name: name.to_string(), kind, uses: Vec::new(), side_effect: false, record: None });
        let index = self.passes.len() - 1;
        PassBuilder { graph: self, index }
    }

    pub fn resource(&self, h: impl GraphHandle) -> &ResourceNode {
        &self.resources[h.raw().0 as usize]
    }

    pub fn resources(&self) -> &[ResourceNode] {
        &self.resources
    }

    pub fn passes(&self) -> &[PassNode] {
        &self.passes
    }

    /// Description of an image resource.
    pub fn image_desc(&self, h: ImageHandle) -> &ImageDesc {
        match &self.resources[h.id as usize].desc {
            ResourceDesc::Image(d) => d,
            ResourceDesc::Buffer(_) => unreachable!("image handle names a buffer"),
        }
    }

    /// Validates, culls and derives barriers. Every problem is reported together.
    pub fn compile(&self) -> Result<CompiledGraph, GraphError> {
        compile::compile(self)
    }

    /// Takes the recording closures out (the executor calls them).
    pub(crate) fn take_records(&mut self) -> Vec<Option<RecordFn>> {
        self.passes.iter_mut().map(|p| p.record.take()).collect()
    }
}

/// Declares a pass's uses, then its recording closure.
pub struct PassBuilder<'g> {
    graph: &'g mut Graph,
    index: usize,
}

impl<'g> PassBuilder<'g> {
    fn declare<H: GraphHandle>(&mut self, h: H, access: Access) -> H {
        let (id, version) = h.raw();
        let info = access.info();
        let pass_name = self.graph.passes[self.index].name.clone();
        let Some(res) = self.graph.resources.get_mut(id as usize) else {
            self.graph.declare_problems.push(Problem::UnknownHandle { pass: pass_name });
            return h;
        };
        if H::IS_IMAGE != res.desc.is_image() {
            self.graph.declare_problems.push(Problem::HandleKind { pass: pass_name, resource: res.name.clone() });
            return h;
        }
        let mut u = Use { resource: id, read_version: None, write_version: None, access };
        let mut out = h;
        if !info.write || info.reads_previous {
            u.read_version = Some(version);
        }
        if info.write {
            if version != res.version {
                self.graph.declare_problems.push(Problem::StaleWrite {
                    pass: pass_name.clone(),
                    resource: res.name.clone(),
                    version,
                    latest: res.version,
                });
            }
            res.version += 1;
            u.write_version = Some(res.version);
            out = h.with_version(res.version);
        }
        self.graph.passes[self.index].uses.push(u);
        out
    }

    /// Declares a read. Returns the handle unchanged.
    pub fn read<H: GraphHandle>(&mut self, h: H, access: Access) -> H {
        if access.is_write() {
            let pass = self.graph.passes[self.index].name.clone();
            let resource = self.graph.resources.get(h.raw().0 as usize).map(|r| r.name.clone()).unwrap_or_default();
            self.graph.declare_problems.push(Problem::WriteDeclaredAsRead { pass, resource, access });
        }
        self.declare(h, access)
    }

    /// Declares a write (or read-modify-write). Returns the new version's handle.
    pub fn write<H: GraphHandle>(&mut self, h: H, access: Access) -> H {
        if !access.is_write() {
            let pass = self.graph.passes[self.index].name.clone();
            let resource = self.graph.resources.get(h.raw().0 as usize).map(|r| r.name.clone()).unwrap_or_default();
            self.graph.declare_problems.push(Problem::ReadDeclaredAsWrite { pass, resource, access });
        }
        self.declare(h, access)
    }

    /// The pass runs even when none of its results is used.
    pub fn side_effect(&mut self) {
        self.graph.passes[self.index].side_effect = true;
    }

    /// Finishes the pass with its recording closure.
    pub fn record(self, f: impl FnOnce(&mut crate::record::RecordContext) -> anyhow::Result<()> + 'static) {
        self.graph.passes[self.index].record = Some(Box::new(f));
    }

    /// Finishes a pass that records nothing (tests, placeholders for culling checks).
    pub fn finish(self) {}
}

#[cfg(test)]
mod tests;
