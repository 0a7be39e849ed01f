//! The particle-particle pass on the GPU (`Backend::step_pairs`): core's `pairs` module
//! mirrored in `wgsl/pairs.wgsl`, run a stage per kernel (`wgsl/pairs_kernel.wgsl`), bit for
//! bit the CPU backend's pass.
//!
//! **Buffers.** The pass sees neighbours across chunks, so its buffers hold every particle:
//! the keys (padded to the table's size with keys that sort last), each particle's place in
//! the sorted order, the bodies, two velocity buffers (Jacobi iterations ping-pong between
//! them), the supports, and the table of bucket ranges, [`pair_table_size`]`(n)` long. The
//! kernels that read or write the particles themselves (the largest speed, the keys, the
//! gather, the starts and the scatter) run per chunk, as the step does; the starts read the
//! chunk's leaf hints, which the march keeps. One small buffer ([`PairState`]) holds the
//! substep's [`PairStep`], the largest speed, the count of valid particles and the report's
//! counts; its counts are the only thing read back (`Backend::take_pair_report`).
//!
//! **A substep** is one compute pass of dispatches, each seeing what the last wrote:
//!
//! | kernel | dispatches | what |
//! |---|---|---|
//! | `pair_reset_kernel` | 1 | the table to `[0, 0]`, the largest speed and valid count to 0 |
//! | `pair_speed_kernel` | 1 per chunk | the largest speed (`atomicMax` on its bits), the fast |
//! | `pair_step_kernel` | 1 (one invocation) | `PairStep::new`'s cell from the largest speed |
//! | `pair_key_kernel` | 1 per chunk | `(hash, index)` |
//! | `pair_sort_block_kernel`, `pair_sort_pass_kernel` | see below | the bitonic sort |
//! | `pair_rank_kernel` | 1 | places, bucket ranges, valid count |
//! | `pair_gather_kernel` | 1 per chunk | bodies in sorted order |
//! | `pair_start_kernel` | 1 per chunk | velocities and supports in sorted order |
//! | `pair_iterate_kernel` | 1 per iteration | a Jacobi iteration |
//! | `pair_scatter_kernel` | 1 per chunk | the valid particles' velocities back |
//! | `step_kernel` (the plain kernel) | 1 per chunk | the march: no gravity, `dt` the substep |
//!
//! The sort of `t` keys (`t = pair_table_size(n)`, a power of two) is one block dispatch
//! (blocks of [`PAIR_SORT_BLOCK`] keys sorted in workgroup memory), then for each longer stage
//! `k` (`2·block` to `t`) its passes at distances `k/2` down to a block, one dispatch each,
//! and a block dispatch for the shorter ones: `1 + Σ (log₂ k − 8)` dispatches, 10 for 4,096
//! keys, 45 for 131,072. Each dispatch's parameters are a [`PairSortParams`] in one uniform
//! buffer, at a dynamic offset. The plain kernel binds nothing of the pass.

use bytemuck::{Pod, Zeroable};
use octoproxy_core::pairs::{
    pair_across, pair_column_table_size, pair_table_size, pair_up, PAIR_HASH_NONE,
};
use octoproxy_core::{
    pair_iterations_for, pair_substeps_for, PairParams, PairProbe, PairReport, PairStep, StepParams,
};

use crate::backend::{storage, uniform, ErrorScope, WgpuBackend, WgpuError};
use crate::shader;

/// The pass's state on the GPU: WGSL's `PairState`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PairState {
    /// The substep's constants; the host writes all but `cell` and `inv_cell`.
    pub step: PairStep,
    /// The substep's largest speed after gravity, as the bits of an `f32`.
    pub v_max: u32,
    /// The valid particles: those before the first key of hash `PAIR_HASH_NONE`.
    pub valid: u32,
    /// Particle-substeps that moved more than a radius (low word).
    pub fast_lo: u32,
    /// Particle-substeps that moved more than a radius (high word).
    pub fast_hi: u32,
    /// Particle-iterations that hit the neighbour cap (low word).
    pub capped_lo: u32,
    /// Particle-iterations that hit the neighbour cap (high word).
    pub capped_hi: u32,
    /// Zero, read by the kernel at run time (the restitution of a grain's support: a
    /// constant one would let the compiler fold `v_n * 0.0` to +0, where IEEE gives -0).
    pub zero: f32,
    /// The pass's relaxation `β` (`PairParams::relaxation`): `pair_step_kernel` puts it in
    /// `step` each substep, after the debiasing iterations ran with zero.
    pub relaxation: f32,
    /// The probe's most particles in one column (`PairProbe::deepest`).
    pub deepest: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
    /// The first unit vector across gravity (`pair_across`), for the probe's columns.
    pub across0: [f32; 4],
    /// The second.
    pub across1: [f32; 4],
}

const _: () = assert!(core::mem::size_of::<PairState>().is_multiple_of(16));

/// The pass's sizes: WGSL's `PairPassParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct PairPassParams {
    /// Particles.
    pub count: u32,
    /// The table's size (`pair_table_size(count)`), also the keys' padded length.
    pub table: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
}

/// One dispatch of the bitonic sort: WGSL's `PairSortParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct PairSortParams {
    /// The stage: the size of the sorted runs it merges into one (the first stage a block
    /// dispatch runs).
    pub k: u32,
    /// The distance compared by a pass over all the keys.
    pub j: u32,
    /// Compare-exchanges of a pass over all the keys (half the padded keys).
    pub threads: u32,
    /// The keys one workgroup sorts in its memory: [`PAIR_SORT_BLOCK`], or all of them when
    /// fewer.
    pub block: u32,
    /// The last stage a block dispatch runs.
    pub k_last: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
}

/// Keys one workgroup of the sort holds in its memory (8 bytes each), two per invocation.
pub const PAIR_SORT_BLOCK: u32 = 512;

/// Storage buffers the pass's kernels bind at most (`pair_start_kernel`: the proxy, the
/// particles and their hints, the state, the ranks, the velocities and the supports).
pub const PAIR_STORAGE_BUFFERS: u32 = 7;

const STATE_BYTES: u64 = core::mem::size_of::<PairState>() as u64;
/// Where the largest speed's bits lie in the state buffer.
const V_MAX_AT: u64 = core::mem::offset_of!(PairState, v_max) as u64;
/// Where the probe's most particles in a column lie in the state buffer.
const DEEPEST_AT: u64 = core::mem::offset_of!(PairState, deepest) as u64;
/// Where the vectors across gravity lie in the state buffer.
const ACROSS_AT: u64 = core::mem::offset_of!(PairState, across0) as u64;
/// Bytes of an entry of the probe's columns (a key and a count).
const COLUMN_BYTES: u64 = 8;
/// Where the report's counts start in the state buffer: `fast_lo`.
const COUNTS_AT: u64 = core::mem::offset_of!(PairState, fast_lo) as u64;
const KEY_BYTES: u64 = 8;
const RANK_BYTES: u64 = 4;
const BODY_BYTES: u64 = core::mem::size_of::<octoproxy_core::PairBody>() as u64;
const VELOCITY_BYTES: u64 = 16;
const RANGE_BYTES: u64 = 8;
const SUPPORT_BYTES: u64 = 16;

/// The pass's pipelines and its one fixed-size buffer.
#[derive(Debug)]
struct PairKernel {
    reset: wgpu::ComputePipeline,
    speed: wgpu::ComputePipeline,
    step: wgpu::ComputePipeline,
    key: wgpu::ComputePipeline,
    sort_pass: wgpu::ComputePipeline,
    sort_block: wgpu::ComputePipeline,
    sort_layout: wgpu::BindGroupLayout,
    rank: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    start: wgpu::ComputePipeline,
    start_given: wgpu::ComputePipeline,
    iterate: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    unbias: wgpu::ComputePipeline,
    regather: wgpu::ComputePipeline,
    state: wgpu::Buffer,
}

/// The buffers for `count` particles, and the bind groups of the kernels that run over them
/// all.
#[derive(Debug)]
struct PairBuffers {
    count: u32,
    table: u32,
    keys: wgpu::Buffer,
    rank: wgpu::Buffer,
    bodies: wgpu::Buffer,
    /// Two for the iterations, and the velocities entering them (`vel[2]`).
    vel: [wgpu::Buffer; 3],
    supports: wgpu::Buffer,
    /// The pass's sizes (`PairPassParams`), and the probe's columns.
    pass: wgpu::Buffer,
    columns: wgpu::Buffer,
    /// In a scene, each particle's support found by the scene module, by upload index.
    pub(crate) given: wgpu::Buffer,
    /// The sort's dispatches, whether each is a block's (or a pass over all the keys), and
    /// their [`PairSortParams`], one every `sort_stride` bytes.
    sort_blocks: Vec<bool>,
    sort_stride: u32,
    reset_group: wgpu::BindGroup,
    step_group: wgpu::BindGroup,
    unbias_group: wgpu::BindGroup,
    sort_group: wgpu::BindGroup,
    rank_group: wgpu::BindGroup,
    /// The first iteration reads `vel[2]` and writes `vel[0]`, the others read `vel[0]` or
    /// `vel[1]` and write the other: iteration `i` uses [`iterate_group`]`(i)`.
    iterate_groups: [wgpu::BindGroup; 3],
}

/// One chunk's bind groups.
#[derive(Debug)]
struct ChunkGroups {
    count: u32,
    speed: wgpu::BindGroup,
    key: wgpu::BindGroup,
    gather: wgpu::BindGroup,
    /// The starts with supports from the proxy's leaves (none without a proxy).
    start: Option<wgpu::BindGroup>,
    /// The starts with the supports given (a scene's).
    start_given: wgpu::BindGroup,
    /// The scatter from `vel[i]`: the last iteration's output is [`last_velocities`]'s.
    scatter: [wgpu::BindGroup; 2],
    /// The marched velocities into `vel[0]`, for the debiasing iterations.
    regather: wgpu::BindGroup,
}

/// What a chunk's bind groups were made for: its particles' buffer, offset and count, its
/// parameters' and hints' buffers, the proxy (if any) and the pass's given supports.
type ChunkKey = (
    wgpu::Buffer,
    u64,
    u32,
    wgpu::Buffer,
    wgpu::Buffer,
    Option<wgpu::Buffer>,
    wgpu::Buffer,
);

/// The backend's pass state.
#[derive(Debug, Default)]
pub(crate) struct PairGpu {
    kernel: Option<PairKernel>,
    buffers: Option<PairBuffers>,
    chunk_keys: Vec<ChunkKey>,
    chunk_groups: Vec<ChunkGroups>,
    /// Steps and substeps since the report was taken (the host counts them).
    pending: PairReport,
}

/// The dispatches that sort `table` keys (a power of two), each a block's (`true`) or a pass
/// over all the keys: the blocks sorted in workgroup memory (every stage up to the block's
/// size), then for each longer stage `k` its passes at distances `k / 2` down to a block,
/// and a block dispatch for the distances below.
fn sort_dispatches(table: u32) -> Vec<(bool, PairSortParams)> {
    let block = table.min(PAIR_SORT_BLOCK);
    let params = |k, j, k_last| PairSortParams {
        k,
        j,
        threads: table / 2,
        block,
        k_last,
        ..Default::default()
    };
    let mut out = Vec::new();
    if table < 2 {
        return out;
    }
    out.push((true, params(2, 0, block)));
    let mut k = 2 * block;
    while k <= table && k != 0 {
        let mut j = k / 2;
        while j >= block {
            out.push((false, params(k, j, k)));
            j /= 2;
        }
        out.push((true, params(k, 0, k)));
        k = k.wrapping_mul(2);
    }
    out
}

/// A bind group of `pipeline`'s own layout (made from its shader) with these bindings.
fn group(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    label: &str,
    entries: &[(u32, wgpu::BindingResource<'_>)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = entries
        .iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry {
            binding: *binding,
            resource: resource.clone(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

impl WgpuBackend {
    pub(crate) fn pair_kernel(&mut self) -> Result<(), WgpuError> {
        if self.pairs.kernel.is_some() {
            return Ok(());
        }
        let limit = self.device.limits().max_storage_buffers_per_shader_stage;
        if limit < PAIR_STORAGE_BUFFERS {
            return Err(WgpuError::TooLarge {
                what: "the particle-particle pass's storage buffers",
                needed: PAIR_STORAGE_BUFFERS as u64,
                limit: limit as u64,
            });
        }
        let scope = ErrorScope::push(&self.device);
        let device = &self.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("octoproxy particle-particle pass"),
            source: wgpu::ShaderSource::Wgsl(shader::pair_source().into()),
        });
        let pipeline = |entry: &str, layout: Option<&wgpu::PipelineLayout>| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let mut sort_uniform = uniform(11, core::mem::size_of::<PairSortParams>() as u64);
        if let wgpu::BindingType::Buffer {
            has_dynamic_offset, ..
        } = &mut sort_uniform.ty
        {
            *has_dynamic_offset = true;
        }
        let sort_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("octoproxy pair sort"),
            entries: &[storage(4, false), sort_uniform],
        });
        let sort_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("octoproxy pair sort"),
            bind_group_layouts: &[Some(&sort_layout)],
            immediate_size: 0,
        });
        let kernel = PairKernel {
            reset: pipeline("pair_reset_kernel", None),
            speed: pipeline("pair_speed_kernel", None),
            step: pipeline("pair_step_kernel", None),
            key: pipeline("pair_key_kernel", None),
            sort_pass: pipeline("pair_sort_pass_kernel", Some(&sort_pipeline_layout)),
            sort_block: pipeline("pair_sort_block_kernel", Some(&sort_pipeline_layout)),
            sort_layout,
            rank: pipeline("pair_rank_kernel", None),
            gather: pipeline("pair_gather_kernel", None),
            start: pipeline("pair_start_kernel", None),
            start_given: pipeline("pair_start_given_kernel", None),
            iterate: pipeline("pair_iterate_kernel", None),
            scatter: pipeline("pair_scatter_kernel", None),
            unbias: pipeline("pair_unbias_kernel", None),
            regather: pipeline("pair_regather_kernel", None),
            state: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("octoproxy pair state"),
                size: STATE_BYTES,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
                // Zeroed: no counts yet.
                mapped_at_creation: false,
            }),
        };
        scope.pop().map_err(WgpuError::Shader)?;
        self.pairs.kernel = Some(kernel);
        Ok(())
    }

    /// The pass's buffers for `n` particles (kept while `n` is the same).
    pub(crate) fn pair_buffers(&mut self, n: usize) -> Result<(), WgpuError> {
        if self
            .pairs
            .buffers
            .as_ref()
            .is_some_and(|b| b.count as usize == n)
        {
            return Ok(());
        }
        self.pairs.buffers = None;
        self.pairs.chunk_keys.clear();
        self.pairs.chunk_groups.clear();
        let table = pair_table_size(n);
        let limits = self.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let sizes = [
            ("the particle-particle pass's bodies", n as u64 * BODY_BYTES),
            (
                "the particle-particle pass's velocities",
                n as u64 * VELOCITY_BYTES,
            ),
            (
                "the particle-particle pass's supports",
                n as u64 * SUPPORT_BYTES,
            ),
            ("the particle-particle pass's ranks", n as u64 * RANK_BYTES),
            (
                "the particle-particle pass's keys",
                table as u64 * KEY_BYTES,
            ),
            (
                "the particle-particle pass's table",
                table as u64 * RANGE_BYTES,
            ),
            (
                "the particle-particle pass's columns",
                pair_column_table_size(n) as u64 * COLUMN_BYTES,
            ),
        ];
        for (what, needed) in sizes {
            // The table's size (and so every index) must fit a u32 below 2^31.
            if needed > limit || table > 1 << 31 {
                return Err(WgpuError::TooLarge {
                    what,
                    needed,
                    limit,
                });
            }
        }
        let kernel = self.pairs.kernel.as_ref().expect("built first");
        let scope = ErrorScope::push(&self.device);
        let device = &self.device;
        let buffer = |label: &str, bytes: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(16),
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let storage_usage = wgpu::BufferUsages::STORAGE;
        let keys = buffer(
            "octoproxy pair keys",
            table as u64 * KEY_BYTES,
            storage_usage,
        );
        // The padding sorts after every particle's key and stays at the end.
        self.queue
            .write_buffer(&keys, 0, bytemuck::cast_slice(&vec![[u32::MAX; 2]; table]));
        let rank = buffer("octoproxy pair ranks", n as u64 * RANK_BYTES, storage_usage);
        let bodies = buffer(
            "octoproxy pair bodies",
            n as u64 * BODY_BYTES,
            storage_usage,
        );
        let vel = [(); 3].map(|_| {
            buffer(
                "octoproxy pair velocities",
                n as u64 * VELOCITY_BYTES,
                storage_usage,
            )
        });
        let supports = buffer(
            "octoproxy pair supports",
            n as u64 * SUPPORT_BYTES,
            storage_usage,
        );
        let given = buffer(
            "octoproxy pair given supports",
            n as u64 * SUPPORT_BYTES,
            storage_usage,
        );
        let ranges = buffer(
            "octoproxy pair table",
            table as u64 * RANGE_BYTES,
            storage_usage,
        );
        let columns = buffer(
            "octoproxy pair columns",
            pair_column_table_size(n) as u64 * COLUMN_BYTES,
            storage_usage,
        );
        let pass = buffer(
            "octoproxy pair sizes",
            core::mem::size_of::<PairPassParams>() as u64,
            wgpu::BufferUsages::UNIFORM,
        );
        let sizes = PairPassParams {
            count: n as u32,
            table: table as u32,
            ..Default::default()
        };
        self.queue
            .write_buffer(&pass, 0, bytemuck::bytes_of(&sizes));
        let stride = limits.min_uniform_buffer_offset_alignment.max(32);
        let passes = sort_dispatches(table as u32);
        let mut bytes = vec![0u8; passes.len().max(1) * stride as usize];
        for (i, (_, p)) in passes.iter().enumerate() {
            let at = i * stride as usize;
            bytes[at..at + 32].copy_from_slice(bytemuck::bytes_of(p));
        }
        let sort = buffer(
            "octoproxy pair sort passes",
            bytes.len() as u64,
            wgpu::BufferUsages::UNIFORM,
        );
        self.queue.write_buffer(&sort, 0, &bytes);
        let state = kernel.state.as_entire_binding();
        let reset_group = group(
            device,
            &kernel.reset,
            "octoproxy pair reset",
            &[
                (3, state.clone()),
                (9, ranges.as_entire_binding()),
                (10, pass.as_entire_binding()),
            ],
        );
        let step_group = group(
            device,
            &kernel.step,
            "octoproxy pair step",
            &[(3, state.clone())],
        );
        let unbias_group = group(
            device,
            &kernel.unbias,
            "octoproxy pair unbias",
            &[(3, state.clone())],
        );
        let sort_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("octoproxy pair sort"),
            layout: &kernel.sort_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: keys.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 11,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &sort,
                        offset: 0,
                        size: wgpu::BufferSize::new(core::mem::size_of::<PairSortParams>() as u64),
                    }),
                },
            ],
        });
        let rank_group = group(
            device,
            &kernel.rank,
            "octoproxy pair ranks",
            &[
                (3, state.clone()),
                (4, keys.as_entire_binding()),
                (5, rank.as_entire_binding()),
                (9, ranges.as_entire_binding()),
                (10, pass.as_entire_binding()),
            ],
        );
        let iterate = |from: usize, to: usize| {
            group(
                device,
                &kernel.iterate,
                "octoproxy pair iteration",
                &[
                    (3, state.clone()),
                    (6, bodies.as_entire_binding()),
                    (7, vel[from].as_entire_binding()),
                    (8, vel[to].as_entire_binding()),
                    (9, ranges.as_entire_binding()),
                    (12, supports.as_entire_binding()),
                    (14, vel[2].as_entire_binding()),
                ],
            )
        };
        let iterate_groups = [iterate(2, 0), iterate(0, 1), iterate(1, 0)];
        scope.pop().map_err(WgpuError::Gpu)?;
        self.pairs.buffers = Some(PairBuffers {
            count: n as u32,
            table: table as u32,
            keys,
            rank,
            bodies,
            vel,
            supports,
            pass,
            columns,
            given,
            sort_blocks: passes.iter().map(|(block, _)| *block).collect(),
            sort_stride: stride,
            reset_group,
            step_group,
            unbias_group,
            sort_group,
            rank_group,
            iterate_groups,
        });
        Ok(())
    }

    /// Each chunk's bind groups, remade when the chunks, the proxy or the pass's buffers
    /// change.
    pub(crate) fn pair_chunk_groups(&mut self) {
        let proxy = self.proxy().map(|(p, _)| p.clone());
        let given = self
            .pairs
            .buffers
            .as_ref()
            .expect("made first")
            .given
            .clone();
        let keys: Vec<ChunkKey> = self
            .chunks
            .iter()
            .map(|c| {
                (
                    c.buffer.clone(),
                    c.offset,
                    c.count,
                    c.params.clone(),
                    c.hints.clone(),
                    proxy.clone(),
                    given.clone(),
                )
            })
            .collect();
        if keys == self.pairs.chunk_keys {
            return;
        }
        let kernel = self.pairs.kernel.as_ref().expect("built first");
        let buffers = self.pairs.buffers.as_ref().expect("made first");
        let device = &self.device;
        let state = kernel.state.as_entire_binding();
        let groups = self
            .chunks
            .iter()
            .map(|chunk| {
                let particles = || {
                    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &chunk.buffer,
                        offset: chunk.offset,
                        size: wgpu::BufferSize::new(
                            chunk.count as u64 * crate::backend::PARTICLE_BYTES,
                        ),
                    })
                };
                let params = chunk.params.as_entire_binding();
                let scatter = |from: usize| {
                    group(
                        device,
                        &kernel.scatter,
                        "octoproxy pair scatter",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (5, buffers.rank.as_entire_binding()),
                            (7, buffers.vel[from].as_entire_binding()),
                        ],
                    )
                };
                ChunkGroups {
                    count: chunk.count,
                    speed: group(
                        device,
                        &kernel.speed,
                        "octoproxy pair speed",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (10, buffers.pass.as_entire_binding()),
                            (16, buffers.columns.as_entire_binding()),
                        ],
                    ),
                    key: group(
                        device,
                        &kernel.key,
                        "octoproxy pair keys",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (4, buffers.keys.as_entire_binding()),
                        ],
                    ),
                    gather: group(
                        device,
                        &kernel.gather,
                        "octoproxy pair gather",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (5, buffers.rank.as_entire_binding()),
                            (6, buffers.bodies.as_entire_binding()),
                        ],
                    ),
                    start: proxy.as_ref().map(|proxy| {
                        group(
                            device,
                            &kernel.start,
                            "octoproxy pair start",
                            &[
                                (0, proxy.as_entire_binding()),
                                (1, particles()),
                                (2, params.clone()),
                                (3, state.clone()),
                                (5, buffers.rank.as_entire_binding()),
                                (8, buffers.vel[2].as_entire_binding()),
                                (12, buffers.supports.as_entire_binding()),
                                (13, chunk.hints.as_entire_binding()),
                            ],
                        )
                    }),
                    start_given: group(
                        device,
                        &kernel.start_given,
                        "octoproxy pair start (given supports)",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (5, buffers.rank.as_entire_binding()),
                            (8, buffers.vel[2].as_entire_binding()),
                            (12, buffers.supports.as_entire_binding()),
                            (15, buffers.given.as_entire_binding()),
                        ],
                    ),
                    scatter: [scatter(0), scatter(1)],
                    regather: group(
                        device,
                        &kernel.regather,
                        "octoproxy pair regather",
                        &[
                            (1, particles()),
                            (2, params.clone()),
                            (3, state.clone()),
                            (5, buffers.rank.as_entire_binding()),
                            (8, buffers.vel[0].as_entire_binding()),
                        ],
                    ),
                }
            })
            .collect();
        self.pairs.chunk_groups = groups;
        self.pairs.chunk_keys = keys;
    }

    /// What every step with the pass checks first: the parameters, the device, and fewer
    /// particles than the pass's keys can number.
    pub(crate) fn check_pass(
        &self,
        params: &StepParams,
        pairs: &PairParams,
    ) -> Result<(), WgpuError> {
        params.validate()?;
        pairs.validate(params)?;
        self.check_health()?;
        if self.count >= PAIR_HASH_NONE as usize {
            return Err(WgpuError::LengthMismatch {
                expected: PAIR_HASH_NONE as usize - 1,
                got: self.count,
            });
        }
        Ok(())
    }

    pub(crate) fn step_pairs_gpu(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
        steps: u32,
    ) -> Result<(), WgpuError> {
        self.check_pass(params, pairs)?;
        let n = self.count;
        let Some((_, baked)) = self.proxy() else {
            return Err(WgpuError::NoProxy);
        };
        octoproxy_core::check_radius(baked, params.radius)?;
        for _ in 0..steps {
            let (substeps, iterations) = self.pair_plan_gpu(params, pairs)?;
            // Gravity is integrated by the pass; the march moves each particle with what it
            // left.
            let march = StepParams {
                gravity: [0.0; 3],
                dt: params.dt / substeps as f32,
                ..*params
            };
            march.validate()?;
            if n > 0 {
                self.record_pairs(params, pairs, &march, substeps, iterations)?;
            }
            self.pair_steps_done(substeps, iterations);
        }
        self.check_health()
    }

    /// The substeps of the next step with the pass (`Backend::pair_substeps_now`): the
    /// probe's largest speed ([`Self::pair_probe_gpu`]), then `pair_substeps_for`.
    pub(crate) fn pair_substeps_gpu(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
    ) -> Result<u32, WgpuError> {
        self.check_pass(params, pairs)?;
        let speed_counts = pairs.substeps == 0 && pairs.follow_speed;
        let probe = self.pair_probe_gpu(params, speed_counts, false)?;
        Ok(pair_substeps_for(params, pairs, probe.speed))
    }

    /// The next step's plan with the pass, from the probe of the particles held (as the CPU
    /// backend's): its substeps (`pair_substeps_for`) and each substep's iterations
    /// (`pair_iterations_for`; a step whose particles stand deeper than they prop up is
    /// counted in the report).
    pub(crate) fn pair_plan_gpu(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
    ) -> Result<(u32, u32), WgpuError> {
        let speed_counts = pairs.substeps == 0 && pairs.follow_speed;
        // Without gravity nothing stacks: the depth changes nothing. With it the depth is
        // probed even when the fewest iterations are also the most, for the report's count of
        // steps deeper than they prop up (the CPU backend's too).
        let depth_counts = pair_up(params) != [0.0; 3];
        let probe = self.pair_probe_gpu(params, speed_counts, depth_counts)?;
        let (iterations, deep) = pair_iterations_for(params, pairs, &probe);
        self.pairs.pending.deep += deep as u64;
        Ok((pair_substeps_for(params, pairs, probe.speed), iterations))
    }

    /// The probe of the particles held (`PairProbe`): their largest speed without gravity
    /// and, with `depth`, the most in one column (`pair_reset_kernel` and `pair_speed_kernel`
    /// with a zero substep, which counts nothing as fast) read back. Waits for the work
    /// queued before it. What is not asked for is left as `PairProbe::default()`'s, and
    /// nothing runs when nothing is.
    fn pair_probe_gpu(
        &mut self,
        params: &StepParams,
        speed: bool,
        depth: bool,
    ) -> Result<PairProbe, WgpuError> {
        let n = self.count;
        if n == 0 || !(speed || depth) {
            return Ok(PairProbe::default());
        }
        self.pair_kernel()?;
        self.pair_buffers(n)?;
        self.pair_chunk_groups();
        let kernel = self.pairs.kernel.as_ref().expect("built above");
        let buffers = self.pairs.buffers.as_ref().expect("made above");
        let scope = ErrorScope::push(&self.device);
        // A zero substep: no gravity, nothing fast, and the columns counted with `depth`
        // (else the diameter's inverse is 0, which the kernel takes for no columns).
        let probe_step = PairStep {
            inv_diameter: if depth {
                1.0 / (2.0 * params.radius)
            } else {
                0.0
            },
            ..PairStep::default()
        };
        self.queue
            .write_buffer(&kernel.state, 0, bytemuck::bytes_of(&probe_step));
        let across = pair_across(params).map(|[x, y, z]| [x, y, z, 0.0]);
        self.queue
            .write_buffer(&kernel.state, ACROSS_AT, bytemuck::cast_slice(&across));
        let mut encoder = self.device.create_command_encoder(&Default::default());
        if depth {
            encoder.clear_buffer(&buffers.columns, 0, None);
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("octoproxy pair speed probe"),
                timestamp_writes: None,
            });
            self.encode_pair_speed(&mut pass, kernel, buffers, false);
        }
        self.queue.submit([encoder.finish()]);
        scope.pop().map_err(WgpuError::Gpu)?;
        let bytes =
            self.read_back(&[(&kernel.state, V_MAX_AT, 4), (&kernel.state, DEEPEST_AT, 4)])?;
        let word = |b: &[u8]| u32::from_le_bytes(b[..4].try_into().expect("4 bytes read back"));
        Ok(PairProbe {
            speed: f32::from_bits(word(&bytes[0])),
            deepest: if depth { word(&bytes[1]) } else { 0 },
        })
    }

    /// The substep's constants for the pass (all but the cell, which the GPU computes from
    /// the largest speed, `pair_step_kernel`; the counts after them are left alone) and the
    /// march's parameters.
    pub(crate) fn write_pair_constants(
        &self,
        params: &StepParams,
        pairs: &PairParams,
        march: &StepParams,
    ) {
        let kernel = self.pairs.kernel.as_ref().expect("built first");
        let buffers = self.pairs.buffers.as_ref().expect("made first");
        let s = PairStep::new(params, pairs, march.dt, buffers.count as usize, 0.0);
        self.queue
            .write_buffer(&kernel.state, 0, bytemuck::bytes_of(&s));
        self.queue.write_buffer(
            &kernel.state,
            core::mem::offset_of!(PairState, relaxation) as u64,
            bytemuck::bytes_of(&pairs.relaxation),
        );
        self.write_step_params(march);
    }

    /// One step of `substeps` substeps of the pass, `march` each substep's march, in one
    /// submission.
    fn record_pairs(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
        march: &StepParams,
        substeps: u32,
        iterations: u32,
    ) -> Result<(), WgpuError> {
        self.pair_kernel()?;
        self.pair_buffers(self.count)?;
        self.pair_chunk_groups();
        let scope = ErrorScope::push(&self.device);
        self.write_pair_constants(params, pairs, march);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        for _ in 0..substeps {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("octoproxy pair substep"),
                timestamp_writes: None,
            });
            self.encode_pair_substep(&mut pass, iterations, None, |pass| {
                self.record_step(pass, false)
            });
        }
        self.queue.submit([encoder.finish()]);
        scope.pop().map_err(WgpuError::Gpu)
    }

    /// The largest speed (`pair_reset_kernel`, then `pair_speed_kernel` per chunk) with the
    /// state's substep as it is.
    fn encode_pair_speed(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        kernel: &PairKernel,
        buffers: &PairBuffers,
        whole_table: bool,
    ) {
        pass.set_pipeline(&kernel.reset);
        pass.set_bind_group(0, &buffers.reset_group, &[]);
        // The reset's first invocation resets the counts; the others, the table's ranges,
        // which only a substep needs (one workgroup leaves the probe a few ranges reset).
        let (x, y) = if whole_table {
            self.dispatch_size(buffers.table)
        } else {
            (1, 1)
        };
        pass.dispatch_workgroups(x, y, 1);
        pass.set_pipeline(&kernel.speed);
        for c in &self.pairs.chunk_groups {
            pass.set_bind_group(0, &c.speed, &[]);
            let (x, y) = self.dispatch_size(c.count);
            pass.dispatch_workgroups(x, y, 1);
        }
    }

    /// One substep of the pass in `pass`: the stages up to the scatter, then `march` (every
    /// particle marched over the substep), then the debiasing stages. With `scene` (the
    /// scene module's support pipeline and each chunk's bind group for it), each grain's
    /// support is found there first and the starts take it (`pair_start_given_kernel`).
    pub(crate) fn encode_pair_substep(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        iterations: u32,
        scene: Option<(&wgpu::ComputePipeline, &[&wgpu::BindGroup])>,
        march: impl FnOnce(&mut wgpu::ComputePass<'_>),
    ) {
        let kernel = self.pairs.kernel.as_ref().expect("built first");
        let buffers = self.pairs.buffers.as_ref().expect("made first");
        let chunks = &self.pairs.chunk_groups;
        let n = buffers.count;
        let dispatch = |pass: &mut wgpu::ComputePass<'_>, count: u32| {
            let (x, y) = self.dispatch_size(count);
            pass.dispatch_workgroups(x, y, 1);
        };
        self.encode_pair_speed(pass, kernel, buffers, true);
        pass.set_pipeline(&kernel.step);
        pass.set_bind_group(0, &buffers.step_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&kernel.key);
        for c in chunks {
            pass.set_bind_group(0, &c.key, &[]);
            dispatch(pass, c.count);
        }
        for (i, &block) in buffers.sort_blocks.iter().enumerate() {
            let offset = i as u32 * buffers.sort_stride;
            if block {
                pass.set_pipeline(&kernel.sort_block);
                pass.set_bind_group(0, &buffers.sort_group, &[offset]);
                let groups = buffers.table / buffers.table.min(PAIR_SORT_BLOCK);
                let (x, y) = self.fold(groups);
                pass.dispatch_workgroups(x, y, 1);
            } else {
                pass.set_pipeline(&kernel.sort_pass);
                pass.set_bind_group(0, &buffers.sort_group, &[offset]);
                dispatch(pass, buffers.table / 2);
            }
        }
        pass.set_pipeline(&kernel.rank);
        pass.set_bind_group(0, &buffers.rank_group, &[]);
        dispatch(pass, n);
        pass.set_pipeline(&kernel.gather);
        for c in chunks {
            pass.set_bind_group(0, &c.gather, &[]);
            dispatch(pass, c.count);
        }
        match scene {
            Some((support, groups)) => {
                pass.set_pipeline(support);
                for (c, group) in chunks.iter().zip(groups) {
                    pass.set_bind_group(0, *group, &[]);
                    dispatch(pass, c.count);
                }
                pass.set_pipeline(&kernel.start_given);
                for c in chunks {
                    pass.set_bind_group(0, &c.start_given, &[]);
                    dispatch(pass, c.count);
                }
            }
            None => {
                pass.set_pipeline(&kernel.start);
                for c in chunks {
                    if let Some(start) = &c.start {
                        pass.set_bind_group(0, start, &[]);
                        dispatch(pass, c.count);
                    }
                }
            }
        }
        pass.set_pipeline(&kernel.iterate);
        for i in 0..iterations {
            pass.set_bind_group(0, &buffers.iterate_groups[iterate_group(i)], &[]);
            dispatch(pass, n);
        }
        pass.set_pipeline(&kernel.scatter);
        let last = last_velocities(iterations);
        for c in chunks {
            pass.set_bind_group(0, &c.scatter[last], &[]);
            dispatch(pass, c.count);
        }
        march(pass);
        // The debiasing iterations: from the marched velocities, in `vel[0]`.
        pass.set_pipeline(&kernel.unbias);
        pass.set_bind_group(0, &buffers.unbias_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&kernel.regather);
        for c in chunks {
            pass.set_bind_group(0, &c.regather, &[]);
            dispatch(pass, c.count);
        }
        pass.set_pipeline(&kernel.iterate);
        for i in 0..iterations {
            pass.set_bind_group(0, &buffers.iterate_groups[1 + i as usize % 2], &[]);
            dispatch(pass, n);
        }
        pass.set_pipeline(&kernel.scatter);
        let last = (iterations % 2) as usize;
        for c in chunks {
            pass.set_bind_group(0, &c.scatter[last], &[]);
            dispatch(pass, c.count);
        }
    }

    /// The pass's buffer of supports given by a scene, once the buffers are made.
    pub(crate) fn pair_given_supports(&self) -> Option<wgpu::Buffer> {
        self.pairs.buffers.as_ref().map(|b| b.given.clone())
    }

    /// Counts one step of `substeps` substeps of `iterations` iterations each for the report.
    pub(crate) fn pair_steps_done(&mut self, substeps: u32, iterations: u32) {
        self.pairs.pending.steps += 1;
        self.pairs.pending.substeps += substeps as u64;
        self.pairs.pending.iterations += substeps as u64 * iterations as u64;
    }

    pub(crate) fn take_pair_report_gpu(&mut self) -> Result<PairReport, WgpuError> {
        self.check_health()?;
        let mut report = std::mem::take(&mut self.pairs.pending);
        if let Some(kernel) = &self.pairs.kernel {
            let bytes = self.read_back(&[(&kernel.state, COUNTS_AT, 16)])?;
            let w: &[u32] = bytemuck::cast_slice(&bytes[0]);
            let wide = |lo: u32, hi: u32| (hi as u64) << 32 | lo as u64;
            report.fast += wide(w[0], w[1]);
            report.capped += wide(w[2], w[3]);
            self.queue
                .write_buffer(&kernel.state, COUNTS_AT, &[0u8; 16]);
        }
        Ok(report)
    }
}

/// Which of [`PairBuffers::iterate_groups`] iteration `i` uses.
fn iterate_group(i: u32) -> usize {
    match i {
        0 => 0,
        _ if i % 2 == 1 => 1,
        _ => 2,
    }
}

/// Which of `vel[0]` and `vel[1]` holds the last of `iterations` (at least 1) iterations'
/// output.
fn last_velocities(iterations: u32) -> usize {
    if iterations % 2 == 1 {
        0
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernels' compare-exchange (`sort_swaps` in WGSL).
    fn swaps(a: [u32; 2], b: [u32; 2], i: u32, k: u32) -> bool {
        if i & k == 0 {
            b < a
        } else {
            a < b
        }
    }

    /// What the dispatches do to `keys`, as the two kernels do it: a block dispatch runs
    /// stages `k..=k_last` on each block at distances below the block, a pass one distance
    /// over all the keys.
    fn run(keys: &mut [[u32; 2]], dispatches: &[(bool, PairSortParams)]) {
        for (block, p) in dispatches {
            if *block {
                for base in (0..keys.len() as u32).step_by(p.block as usize) {
                    let mut k = p.k;
                    loop {
                        let mut j = (k / 2).min(p.block / 2);
                        while j > 0 {
                            for t in 0..p.block / 2 {
                                let i = ((t & !(j - 1)) << 1) | (t & (j - 1));
                                let (a, b) = ((base + i) as usize, (base + (i | j)) as usize);
                                if swaps(keys[a], keys[b], base + i, k) {
                                    keys.swap(a, b);
                                }
                            }
                            j /= 2;
                        }
                        if k >= p.k_last {
                            break;
                        }
                        k *= 2;
                    }
                }
            } else {
                let j = p.j;
                for t in 0..p.threads {
                    let i = ((t & !(j - 1)) << 1) | (t & (j - 1));
                    let (a, b) = (i as usize, (i | j) as usize);
                    if swaps(keys[a], keys[b], i, p.k) {
                        keys.swap(a, b);
                    }
                }
            }
        }
    }

    #[test]
    fn the_sort_dispatches_sort_every_size() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for log in 0..=17 {
            let t = 1usize << log;
            let dispatches = sort_dispatches(t as u32);
            let expected = match t {
                1 => 0,
                _ if t <= PAIR_SORT_BLOCK as usize => 1,
                _ => {
                    let m = log as u32;
                    1 + (10..=m).map(|m| m - 8).sum::<u32>() as usize
                }
            };
            assert_eq!(dispatches.len(), expected, "{t} keys");
            // Few distinct hashes (long runs of one hash, ordered by index), some left out,
            // and the padding.
            let n = t - t / 5;
            let mut keys: Vec<[u32; 2]> = (0..t)
                .map(|i| match i {
                    _ if i >= n => [u32::MAX; 2],
                    _ if next() % 7 == 0 => [PAIR_HASH_NONE, i as u32],
                    _ => [(next() % 13) as u32, i as u32],
                })
                .collect();
            keys.reverse();
            let mut want = keys.clone();
            want.sort_unstable();
            run(&mut keys, &dispatches);
            assert_eq!(keys, want, "{t} keys");
        }
        assert_eq!(sort_dispatches(4096).len(), 10);
        assert_eq!(sort_dispatches(1 << 17).len(), 45);
    }
}
