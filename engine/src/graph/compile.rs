//! Graph compilation: validation, culling, barrier derivation, lifetimes.

use super::access::{has_stencil, is_depth_format, Access, AccessInfo, Applies};
use super::{Graph, Origin, PassKind, ResourceDesc, Usage};
use ash::vk;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;

/// One problem found while validating a graph. Every variant names the pass and resource.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Problem {
    DuplicateResource {
        resource: String,
    },
    DuplicatePass {
        pass: String,
    },
    UnknownHandle {
        pass: String,
    },
    HandleKind {
        pass: String,
        resource: String,
    },
    StaleWrite {
        pass: String,
        resource: String,
        version: u32,
        latest: u32,
    },
    StaleRead {
        pass: String,
        resource: String,
        version: u32,
        latest: u32,
    },
    WriteDeclaredAsRead {
        pass: String,
        resource: String,
        access: Access,
    },
    ReadDeclaredAsWrite {
        pass: String,
        resource: String,
        access: Access,
    },
    ReadBeforeWrite {
        pass: String,
        resource: String,
    },
    AccessKind {
        pass: String,
        resource: String,
        access: Access,
        is_image: bool,
    },
    Format {
        pass: String,
        resource: String,
        access: Access,
        format: vk::Format,
    },
    MissingUsage {
        pass: String,
        resource: String,
        access: Access,
        needed: String,
    },
    ConflictingLayouts {
        pass: String,
        resource: String,
        accesses: Vec<Access>,
    },
    PassKind {
        pass: String,
        kind: PassKind,
        access: Access,
    },
    /// Reported at record time: the pass used a handle it did not declare.
    Undeclared {
        pass: String,
        resource: String,
    },
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Problem::DuplicateResource { resource } => write!(f, "resource '{resource}' is declared twice"),
            Problem::DuplicatePass { pass } => write!(f, "pass '{pass}' is declared twice"),
            Problem::UnknownHandle { pass } => write!(f, "pass '{pass}' uses a handle from another graph"),
            Problem::HandleKind { pass, resource } => {
                write!(f, "pass '{pass}' uses '{resource}' through a handle of the wrong type")
            }
            Problem::StaleWrite { pass, resource, version, latest } => write!(
                f,
                "pass '{pass}' writes '{resource}' v{version}, but v{latest} is the latest (a write must build on the latest version)"
            ),
            Problem::StaleRead { pass, resource, version, latest } => write!(
                f,
                "pass '{pass}' reads '{resource}' v{version}, which an earlier pass already overwrote (latest v{latest})"
            ),
            Problem::WriteDeclaredAsRead { pass, resource, access } => {
                write!(f, "pass '{pass}' declares the write access {access:?} on '{resource}' with read()")
            }
            Problem::ReadDeclaredAsWrite { pass, resource, access } => {
                write!(f, "pass '{pass}' declares the read access {access:?} on '{resource}' with write()")
            }
            Problem::ReadBeforeWrite { pass, resource } => write!(
                f,
                "pass '{pass}' reads '{resource}', which no pass wrote and which was not imported"
            ),
            Problem::AccessKind { pass, resource, access, is_image } => write!(
                f,
                "pass '{pass}' declares {access:?} on '{resource}', which is {} (the access applies to {:?} only)",
                if *is_image { "an image" } else { "a buffer" },
                access.info().applies
            ),
            Problem::Format { pass, resource, access, format } => {
                write!(f, "pass '{pass}' declares {access:?} on '{resource}', whose format {format:?} does not fit it")
            }
            Problem::MissingUsage { pass, resource, access, needed } => write!(
                f,
                "pass '{pass}' declares {access:?} on imported '{resource}', which lacks usage {needed}"
            ),
            Problem::ConflictingLayouts { pass, resource, accesses } => write!(
                f,
                "pass '{pass}' declares {accesses:?} on '{resource}': they need different image layouts at once"
            ),
            Problem::PassKind { pass, access: Access::Present, .. } => write!(
                f,
                "pass '{pass}' declares Present, which is only an imported image's initial or final access"
            ),
            Problem::PassKind { pass, kind, access } => {
                write!(f, "pass '{pass}' is a {kind:?} pass but declares {access:?}")
            }
            Problem::Undeclared { pass, resource } => {
                write!(f, "pass '{pass}' used '{resource}' without declaring it")
            }
        }
    }
}

/// All problems of a graph, reported together.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraphError {
    pub problems: Vec<Problem>,
}

impl fmt::Display for GraphError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "render graph has {} problem(s):", self.problems.len())?;
        for p in &self.problems {
            writeln!(f, "  - {p}")?;
        }
        Ok(())
    }
}

impl std::error::Error for GraphError {}

/// The synchronization state of a resource between accesses (also carried across frames for
/// persistent resources).
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct ResourceState {
    pub layout: vk::ImageLayout,
    /// Stages of the last write (plus stages that chained on it since).
    pub write_stage: vk::PipelineStageFlags2,
    /// Access mask of the last write (what must be made available).
    pub write_access: vk::AccessFlags2,
    /// Stages that read since the last write (a later write must wait for them).
    pub read_stages: vk::PipelineStageFlags2,
    /// (stages, accesses) the last write has been made visible to.
    pub visible: Vec<(vk::PipelineStageFlags2, vk::AccessFlags2)>,
}

/// Why a barrier exists.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub enum BarrierReason {
    /// Image layout transition (may also carry a RAW/WAR/WAW dependency).
    Layout,
    ReadAfterWrite,
    WriteAfterRead,
    WriteAfterWrite,
    /// To the state an imported/readback resource must be left in after the frame.
    Final,
}

/// One image or buffer barrier.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Barrier {
    pub resource: u32,
    pub name: String,
    pub image: bool,
    pub src_stage: vk::PipelineStageFlags2,
    pub src_access: vk::AccessFlags2,
    pub dst_stage: vk::PipelineStageFlags2,
    pub dst_access: vk::AccessFlags2,
    pub old_layout: vk::ImageLayout,
    pub new_layout: vk::ImageLayout,
    pub reason: BarrierReason,
}

/// A pass after compilation.
#[derive(Clone, Debug)]
pub struct CompiledPass {
    pub name: String,
    pub kind: PassKind,
    /// `Some(reason)` if culled.
    pub culled: Option<String>,
    pub side_effect: bool,
    /// Barriers recorded before the pass, in one `vkCmdPipelineBarrier2`.
    pub barriers: Vec<Barrier>,
    /// (resource, access, read version, written version) in declaration order.
    pub uses: Vec<(u32, Access, Option<u32>, Option<u32>)>,
}

/// A resource after compilation.
#[derive(Clone, Debug)]
pub struct ResourceInfo {
    pub name: String,
    pub desc: ResourceDesc,
    pub origin: &'static str,
    pub transient: bool,
    /// Index of the first and last live pass using it.
    pub first_pass: Option<usize>,
    pub last_pass: Option<usize>,
    /// Usage flags needed by the live accesses (images).
    pub image_usage: vk::ImageUsageFlags,
    /// Usage flags needed by the live accesses (buffers).
    pub buffer_usage: vk::BufferUsageFlags,
    pub bytes: u64,
    pub output: bool,
    /// State after the frame (for persistent resources: the next frame's initial state).
    pub final_state: ResourceState,
}

/// The result of [`Graph::compile`].
#[derive(Clone, Debug)]
pub struct CompiledGraph {
    pub passes: Vec<CompiledPass>,
    pub resources: Vec<ResourceInfo>,
    /// Barriers after the last pass (imported outputs, readbacks).
    pub final_barriers: Vec<Barrier>,
}

impl CompiledGraph {
    pub fn live_passes(&self) -> impl Iterator<Item = (usize, &CompiledPass)> {
        self.passes.iter().enumerate().filter(|(_, p)| p.culled.is_none())
    }
    pub fn barrier_count(&self) -> usize {
        self.passes.iter().map(|p| p.barriers.len()).sum::<usize>() + self.final_barriers.len()
    }
    pub fn pass(&self, name: &str) -> Option<&CompiledPass> {
        self.passes.iter().find(|p| p.name == name)
    }
}

fn origin_name(o: &Origin) -> &'static str {
    match o {
        Origin::Transient => "transient",
        Origin::Imported { .. } => "imported",
        Origin::Persistent { .. } => "persistent",
        Origin::HostInit => "host-init",
        Origin::Readback => "readback",
    }
}

/// Merges several accesses of one resource within one pass into one.
fn merge(accesses: &[Access]) -> AccessInfo {
    let mut info = accesses[0].info();
    for a in &accesses[1..] {
        let i = a.info();
        info.stage |= i.stage;
        info.access |= i.access;
        info.write |= i.write;
        info.reads_previous |= i.reads_previous;
        info.image_usage |= i.image_usage;
        info.buffer_usage |= i.buffer_usage;
    }
    info
}

fn covered(state: &ResourceState, info: &AccessInfo) -> bool {
    state.visible.iter().any(|(s, a)| s.contains(info.stage) && a.contains(info.access))
}

/// Applies one access to a resource state; returns the barrier it needs, if any.
pub(crate) fn transition(
    state: &mut ResourceState,
    info: &AccessInfo,
    is_image: bool,
) -> Option<(vk::PipelineStageFlags2, vk::AccessFlags2, vk::ImageLayout, BarrierReason)> {
    let prior_stages = state.write_stage | state.read_stages;
    let src_stage = if prior_stages.is_empty() { vk::PipelineStageFlags2::NONE } else { prior_stages };
    if is_image && state.layout != info.layout {
        let old = state.layout;
        let src_access = state.write_access;
        if info.write {
            state.write_stage = info.stage;
            state.write_access = info.access;
            state.read_stages = vk::PipelineStageFlags2::empty();
            state.visible.clear();
        } else {
            // The transition is a write ordered before `info.stage`: later readers chain on it.
            state.write_stage |= info.stage;
            state.read_stages = info.stage;
            state.visible = vec![(info.stage, info.access)];
        }
        state.layout = info.layout;
        return Some((src_stage, src_access, old, BarrierReason::Layout));
    }
    if info.write {
        let had_write = !state.write_stage.is_empty();
        let had_reads = !state.read_stages.is_empty();
        let src_access = state.write_access;
        state.write_stage = info.stage;
        state.write_access = info.access;
        state.read_stages = vk::PipelineStageFlags2::empty();
        state.visible.clear();
        if !had_write && !had_reads {
            return None;
        }
        let reason = if had_reads { BarrierReason::WriteAfterRead } else { BarrierReason::WriteAfterWrite };
        return Some((src_stage, src_access, state.layout, reason));
    }
    // Read.
    state.read_stages |= info.stage;
    if state.write_stage.is_empty() || covered(state, info) {
        return None;
    }
    state.visible.push((info.stage, info.access));
    Some((state.write_stage, state.write_access, state.layout, BarrierReason::ReadAfterWrite))
}

/// Applies `info` to resource `rid`'s state and builds the barrier it needs, if any
/// (`reason` overrides the derived one, for final barriers).
fn barrier_for(
    rid: u32,
    res: &super::ResourceNode,
    state: &mut ResourceState,
    info: &AccessInfo,
    reason: Option<BarrierReason>,
) -> Option<Barrier> {
    let is_image = res.desc.is_image();
    let (src_stage, src_access, old_layout, derived) = transition(state, info, is_image)?;
    Some(Barrier {
        resource: rid,
        name: res.name.clone(),
        image: is_image,
        src_stage,
        src_access,
        dst_stage: info.stage,
        dst_access: info.access,
        old_layout,
        new_layout: if is_image { info.layout } else { vk::ImageLayout::UNDEFINED },
        reason: reason.unwrap_or(derived),
    })
}

fn initial_state(origin: &Origin) -> ResourceState {
    match origin {
        Origin::Imported { initial, initial_layout, .. } => {
            let mut s = ResourceState { layout: *initial_layout, ..Default::default() };
            if let Some(a) = initial {
                let i = a.info();
                if i.applies != Applies::Buffer {
                    s.layout = i.layout;
                }
                if i.write {
                    s.write_stage = i.stage;
                    s.write_access = i.access;
                } else {
                    s.read_stages = i.stage;
                }
            }
            s
        }
        Origin::Persistent { state: Some(s) } => s.clone(),
        _ => ResourceState::default(),
    }
}

pub(crate) fn compile(g: &Graph) -> Result<CompiledGraph, GraphError> {
    let mut problems = g.declare_problems.clone();
    let nres = g.resources.len();

    // ---- per-use validation and the writer of each version
    let mut writer: BTreeMap<(u32, u32), usize> = BTreeMap::new();
    let mut latest = vec![0u32; nres];
    for r in g.resources.iter().enumerate() {
        if matches!(r.1.origin, Origin::HostInit) {
            latest[r.0] = 1;
        }
    }
    for (pi, p) in g.passes.iter().enumerate() {
        let mut by_res: BTreeMap<u32, Vec<Access>> = BTreeMap::new();
        for u in &p.uses {
            let Some(r) = g.resources.get(u.resource as usize) else { continue };
            let info = u.access.info();
            let is_image = r.desc.is_image();
            let kind_ok = match info.applies {
                Applies::Image => is_image,
                Applies::Buffer => !is_image,
                Applies::Both => true,
            };
            if !kind_ok {
                problems.push(Problem::AccessKind {
                    pass: p.name.clone(),
                    resource: r.name.clone(),
                    access: u.access,
                    is_image,
                });
            }
            if let (ResourceDesc::Image(d), Some(want_depth)) = (&r.desc, info.depth_format) {
                // Depth-only layouts cannot describe a stencil aspect, and the other way round.
                let stencil_mismatch = want_depth
                    && match u.access {
                        Access::DepthAttachmentWrite | Access::DepthAttachmentRead => has_stencil(d.format),
                        Access::DepthStencilAttachmentWrite | Access::DepthStencilAttachmentRead => {
                            !has_stencil(d.format)
                        }
                        _ => false,
                    };
                if is_depth_format(d.format) != want_depth || stencil_mismatch {
                    problems.push(Problem::Format {
                        pass: p.name.clone(),
                        resource: r.name.clone(),
                        access: u.access,
                        format: d.format,
                    });
                }
            }
            if let Origin::Imported { usage, .. } = &r.origin {
                let missing = match usage {
                    Usage::Image(have) if !have.contains(info.image_usage) => {
                        Some(format!("{:?}", info.image_usage & !*have))
                    }
                    Usage::Buffer(have) if !have.contains(info.buffer_usage) => {
                        Some(format!("{:?}", info.buffer_usage & !*have))
                    }
                    _ => None,
                };
                if let Some(needed) = missing {
                    problems.push(Problem::MissingUsage {
                        pass: p.name.clone(),
                        resource: r.name.clone(),
                        access: u.access,
                        needed,
                    });
                }
            }
            let kind_fits = match p.kind {
                PassKind::Transfer => matches!(u.access, Access::TransferSrc | Access::TransferDst | Access::HostRead),
                PassKind::Compute => !matches!(
                    u.access,
                    Access::ColorAttachmentWrite
                        | Access::ColorAttachmentReadWrite
                        | Access::DepthAttachmentRead
                        | Access::DepthAttachmentWrite
                        | Access::DepthStencilAttachmentRead
                        | Access::DepthStencilAttachmentWrite
                        | Access::VertexBuffer
                        | Access::IndexBuffer
                        | Access::VertexShaderReadSampled
                        | Access::VertexShaderReadStorage
                        | Access::FragmentShaderReadSampled
                        | Access::FragmentShaderReadStorage
                ),
                PassKind::Raster => !matches!(
                    u.access,
                    Access::ComputeShaderReadSampled
                        | Access::ComputeShaderReadStorage
                        | Access::ComputeShaderWriteStorage
                        | Access::ComputeShaderReadWriteStorage
                ),
            };
            // `Present` describes the presentation engine's ownership, not a pass's work.
            if !kind_fits || u.access == Access::Present {
                problems.push(Problem::PassKind { pass: p.name.clone(), kind: p.kind, access: u.access });
            }
            if let Some(v) = u.read_version {
                let readable_v0 = matches!(r.origin, Origin::Imported { .. } | Origin::Persistent { .. });
                if v == 0 && !readable_v0 {
                    problems.push(Problem::ReadBeforeWrite { pass: p.name.clone(), resource: r.name.clone() });
                } else if v < latest[u.resource as usize] {
                    problems.push(Problem::StaleRead {
                        pass: p.name.clone(),
                        resource: r.name.clone(),
                        version: v,
                        latest: latest[u.resource as usize],
                    });
                }
            }
            if let Some(v) = u.write_version {
                writer.insert((u.resource, v), pi);
                latest[u.resource as usize] = latest[u.resource as usize].max(v);
            }
            by_res.entry(u.resource).or_default().push(u.access);
        }
        for (rid, accesses) in &by_res {
            let r = &g.resources[*rid as usize];
            if r.desc.is_image() {
                let layouts: BTreeSet<i32> = accesses.iter().map(|a| a.info().layout.as_raw()).collect();
                if layouts.len() > 1 {
                    problems.push(Problem::ConflictingLayouts {
                        pass: p.name.clone(),
                        resource: r.name.clone(),
                        accesses: accesses.clone(),
                    });
                }
            }
        }
    }
    if !problems.is_empty() {
        return Err(GraphError { problems });
    }

    // ---- culling from the outputs
    let mut live = vec![false; g.passes.len()];
    let mut work: Vec<usize> = Vec::new();
    for (pi, p) in g.passes.iter().enumerate() {
        if p.side_effect {
            live[pi] = true;
            work.push(pi);
        }
    }
    for (ri, r) in g.resources.iter().enumerate() {
        let is_output = r.output
            || matches!(r.origin, Origin::Persistent { .. } | Origin::Readback)
            || matches!(r.origin, Origin::Imported { final_access: Some(_), .. });
        if is_output {
            if let Some(&pi) = writer.get(&(ri as u32, latest[ri])) {
                if !live[pi] {
                    live[pi] = true;
                    work.push(pi);
                }
            }
        }
    }
    while let Some(pi) = work.pop() {
        for u in &g.passes[pi].uses {
            if let Some(v) = u.read_version {
                if let Some(&w) = writer.get(&(u.resource, v)) {
                    if !live[w] {
                        live[w] = true;
                        work.push(w);
                    }
                }
            }
        }
    }

    // ---- barriers over the live passes, in recording order
    let mut states: Vec<ResourceState> = g.resources.iter().map(|r| initial_state(&r.origin)).collect();
    let mut first = vec![None; nres];
    let mut last = vec![None; nres];
    let mut image_usage = vec![vk::ImageUsageFlags::empty(); nres];
    let mut buffer_usage = vec![vk::BufferUsageFlags::empty(); nres];
    let mut passes = Vec::with_capacity(g.passes.len());
    for (pi, p) in g.passes.iter().enumerate() {
        let uses = p.uses.iter().map(|u| (u.resource, u.access, u.read_version, u.write_version)).collect();
        if !live[pi] {
            let written: Vec<String> = p
                .uses
                .iter()
                .filter_map(|u| u.write_version.map(|v| format!("{} v{v}", g.resources[u.resource as usize].name)))
                .collect();
            let reason = if written.is_empty() {
                "writes nothing and has no side effect".to_string()
            } else {
                format!("no live pass reads what it writes ({}) and none of it is a graph output", written.join(", "))
            };
            passes.push(CompiledPass {
                name: p.name.clone(),
                kind: p.kind,
                culled: Some(reason),
                side_effect: p.side_effect,
                barriers: Vec::new(),
                uses,
            });
            continue;
        }
        let mut by_res: BTreeMap<u32, Vec<Access>> = BTreeMap::new();
        for u in &p.uses {
            by_res.entry(u.resource).or_default().push(u.access);
        }
        let mut barriers = Vec::new();
        for (rid, accesses) in by_res {
            let r = rid as usize;
            let res = &g.resources[r];
            let info = merge(&accesses);
            first[r].get_or_insert(pi);
            last[r] = Some(pi);
            image_usage[r] |= info.image_usage;
            buffer_usage[r] |= info.buffer_usage;
            barriers.extend(barrier_for(rid, res, &mut states[r], &info, None));
        }
        passes.push(CompiledPass {
            name: p.name.clone(),
            kind: p.kind,
            culled: None,
            side_effect: p.side_effect,
            barriers,
            uses,
        });
    }

    // ---- final states of outputs
    let mut final_barriers = Vec::new();
    for (r, res) in g.resources.iter().enumerate() {
        let final_access = match &res.origin {
            Origin::Imported { final_access: Some(a), .. } => Some(*a),
            Origin::Readback if last[r].is_some() => Some(Access::HostRead),
            _ => None,
        };
        if let Some(a) = final_access {
            final_barriers.extend(barrier_for(r as u32, res, &mut states[r], &a.info(), Some(BarrierReason::Final)));
        }
    }

    let resources = g
        .resources
        .iter()
        .enumerate()
        .map(|(r, res)| ResourceInfo {
            name: res.name.clone(),
            desc: res.desc.clone(),
            origin: origin_name(&res.origin),
            transient: matches!(res.origin, Origin::Transient | Origin::HostInit | Origin::Readback),
            first_pass: first[r],
            last_pass: last[r],
            image_usage: image_usage[r],
            buffer_usage: buffer_usage[r],
            bytes: res.desc.bytes(),
            output: res.output,
            final_state: states[r].clone(),
        })
        .collect();
    Ok(CompiledGraph { passes, resources, final_barriers })
}
