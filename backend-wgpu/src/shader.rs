//! The WGSL source of the kernel: the constants, generated from the Rust ones so the two
//! sides cannot drift, followed by the hand-written mirror of core's routine.
//!
//! The `.wgsl` files beside this module mirror core's modules: `format.wgsl` (node records,
//! header, `decode_normal`, `grid_plane`), `particle.wgsl` (`Particle`, `StepParams`),
//! `query.wgsl` (`locate_inside` and its helpers), `step.wgsl` (`step_particle_hinted`, its
//! settles and the march's steps), `pose.wgsl`, `observe.wgsl` and `scene.wgsl` (scenes:
//! poses, the march's observer, the scene step), `pairs.wgsl` (the particle-particle pass),
//! and the entry points. They make three modules: the plain kernel ([`FILES`], whose march
//! observes nothing: `observe_none.wgsl`), the scene kernel ([`SCENE_FILES`]) and the
//! particle-particle pass ([`PAIR_FILES`]: the plain kernel's step, for the grains' supports,
//! then `pairs.wgsl` and `pairs_kernel.wgsl`, which runs it stage by stage). Every function
//! has a Rust twin or a stated reason for none; the table is in `tests/wgsl.rs`.

use octoproxy_core::format::{self, header};
use octoproxy_core::pairs;
use octoproxy_core::scene::{self as sc, BROAD_LEAF, SIDE_SLOTS};
use octoproxy_core::*;

/// Invocations per workgroup of the scene kernel and the particle-particle pass's stages, and
/// the unit chunks are rounded to.
pub const WORKGROUP_SIZE: u32 = 64;

/// Invocations per workgroup of the plain step by default (lowered to the device's limit). On
/// an H200 it was the fastest of 32, 64, 128 and 256 for every bench scene at 1M, 3M and 10M
/// particles, by 3-9 % over 64 (the device check of 2026-12-04, `docs/bench/gpu/`).
/// [`crate::WgpuBackend::set_workgroup_size`] changes it; every size steps the same bits.
pub const STEP_WORKGROUP_SIZE: u32 = 256;

const FORMAT: (&str, &str) = ("format.wgsl", include_str!("wgsl/format.wgsl"));
const PARTICLE: (&str, &str) = ("particle.wgsl", include_str!("wgsl/particle.wgsl"));
const QUERY: (&str, &str) = ("query.wgsl", include_str!("wgsl/query.wgsl"));
const STEP: (&str, &str) = ("step.wgsl", include_str!("wgsl/step.wgsl"));
const OBSERVE_NONE: (&str, &str) = ("observe_none.wgsl", include_str!("wgsl/observe_none.wgsl"));
const SUPPORT: (&str, &str) = ("support.wgsl", include_str!("wgsl/support.wgsl"));

/// The plain kernel's hand-written WGSL files in the order they are joined, each with its name.
pub const FILES: [(&str, &str); 6] = [
    FORMAT,
    PARTICLE,
    QUERY,
    OBSERVE_NONE,
    STEP,
    ("kernel.wgsl", include_str!("wgsl/kernel.wgsl")),
];

/// The scene kernel's files, in the order they are joined: the plain kernel's step with the
/// scene step around it, and an observer that records hits and events.
pub const SCENE_FILES: [(&str, &str); 9] = [
    FORMAT,
    PARTICLE,
    QUERY,
    ("pose.wgsl", include_str!("wgsl/pose.wgsl")),
    ("observe.wgsl", include_str!("wgsl/observe.wgsl")),
    STEP,
    SUPPORT,
    ("scene.wgsl", include_str!("wgsl/scene.wgsl")),
    ("scene_kernel.wgsl", include_str!("wgsl/scene_kernel.wgsl")),
];

/// The particle-particle pass's files, in the order they are joined: the plain kernel's step
/// (a grain's support is the surface leaf of its hint, and the scene's response to it is
/// `respond`), the pass's mirror of core's `pairs` module, and its entry points. The march
/// that follows the pass is the plain kernel's.
pub const PAIR_FILES: [(&str, &str); 8] = [
    FORMAT,
    PARTICLE,
    QUERY,
    OBSERVE_NONE,
    STEP,
    SUPPORT,
    ("pairs.wgsl", include_str!("wgsl/pairs.wgsl")),
    ("pairs_kernel.wgsl", include_str!("wgsl/pairs_kernel.wgsl")),
];

/// A constant shared by Rust and WGSL.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SharedValue {
    /// A `u32` constant.
    U32(u32),
    /// An `f32` constant.
    F32(f32),
}

/// Codes of [`StepOutcome`] in WGSL, where enums do not exist.
pub const fn outcome_code(outcome: StepOutcome) -> u32 {
    match outcome {
        StepOutcome::Done => 0,
        StepOutcome::Blocked => 1,
        StepOutcome::BoundHit => 2,
        StepOutcome::Invalid => 3,
    }
}

/// Every constant the WGSL reads, by name, with its value taken from the Rust side.
pub fn shared_constants() -> Vec<(&'static str, SharedValue)> {
    use SharedValue::{F32, U32};
    let h = |i: usize| U32(i as u32);
    vec![
        ("MAGIC", U32(format::MAGIC)),
        ("FORMAT_VERSION", U32(FORMAT_VERSION)),
        ("HEADER_WORDS", U32(format::HEADER_WORDS as u32)),
        ("NODE_WORDS", U32(format::NODE_WORDS as u32)),
        ("HEADER_LUT_DEPTH", h(header::LUT_DEPTH)),
        ("HEADER_LUT_OFFSET", h(header::LUT_OFFSET)),
        ("HEADER_TREE_DEPTH", h(header::TREE_DEPTH)),
        ("HEADER_DMAX", h(header::DMAX)),
        ("HEADER_ROOT_MIN", h(header::ROOT_MIN)),
        ("HEADER_ROOT_SIZE", h(header::ROOT_SIZE)),
        ("MAX_DEPTH", U32(MAX_DEPTH)),
        ("INV_GRID_CELLS", F32(1.0 / (1u32 << MAX_DEPTH) as f32)),
        ("CHILD_MASK_SHIFT", U32(format::CHILD_MASK_SHIFT)),
        ("INTERNAL_MASK_SHIFT", U32(format::INTERNAL_MASK_SHIFT)),
        ("LABEL_SHIFT", U32(format::LABEL_SHIFT)),
        ("LEAF_BIT", U32(format::LEAF_BIT)),
        ("TWO_SIDED_BIT", U32(format::TWO_SIDED_BIT)),
        ("OCT_BITS", U32(format::OCT_BITS)),
        ("OCT_MAX", U32(format::OCT_MAX)),
        ("OCT_MASK", U32((1 << (2 * format::OCT_BITS)) - 1)),
        ("INV_OCT_MAX", F32(1.0 / format::OCT_MAX as f32)),
        ("LUT_INDEX_MASK", U32(format::LUT_INDEX_MASK)),
        ("LUT_DEPTH_SHIFT", U32(format::LUT_DEPTH_SHIFT)),
        ("LABEL_NONE", U32(Label::None.bits())),
        ("LABEL_FRONT", U32(Label::Front.bits())),
        ("LABEL_BACK", U32(Label::Back.bits())),
        ("LEAF_EMPTY", U32(LeafKind::Empty as u32)),
        ("LEAF_SURFACE", U32(LeafKind::Surface as u32)),
        ("SIDE_FRONT", U32(SIDE_FRONT)),
        ("SIDE_BACK", U32(SIDE_BACK)),
        ("SIDE_MASK", U32(SIDE_MASK)),
        ("SIDE_CAGED", U32(SIDE_CAGED)),
        ("SIDE_EXITS_SHIFT", U32(SIDE_EXITS_SHIFT)),
        ("SIDE_CAGE_MASK", U32(SIDE_CAGE_MASK)),
        ("SIDE_EXITS_MASK", U32(SIDE_EXITS_MASK)),
        ("SIDE_SLAB", U32(SIDE_SLAB)),
        ("CLEARANCE_BITS", U32(format::CLEARANCE_BITS)),
        ("CLEARANCE_MAX", U32(format::CLEARANCE_MAX)),
        ("CLEARANCE_STEPS", U32(format::CLEARANCE_STEPS)),
        ("F32_MIN_POSITIVE", F32(f32::MIN_POSITIVE)),
        ("FLAG_INVALID", U32(FLAG_INVALID)),
        ("FLAG_BOUND_HIT", U32(FLAG_BOUND_HIT)),
        ("FLAG_BLOCKED", U32(FLAG_BLOCKED)),
        ("FLAG_STEP_STATUS", U32(FLAG_STEP_STATUS)),
        ("FLAG_STATUS_MASK", U32(FLAG_STATUS_MASK)),
        ("COLLISION_SHIFT", U32(COLLISION_SHIFT)),
        ("MAX_COLLISIONS", U32(MAX_COLLISIONS)),
        ("STEP_DONE", U32(outcome_code(StepOutcome::Done))),
        ("STEP_BLOCKED", U32(outcome_code(StepOutcome::Blocked))),
        ("STEP_BOUND_HIT", U32(outcome_code(StepOutcome::BoundHit))),
        ("STEP_INVALID", U32(outcome_code(StepOutcome::Invalid))),
        ("NO_LEAF", U32(NO_LEAF)),
        ("LEAF_BOUND_PER_CELL", U32(LEAF_BOUND_PER_CELL)),
        ("LEAF_BOUND_EXTRA", U32(LEAF_BOUND_EXTRA)),
        ("PINCH_PARALLEL", F32(PINCH_PARALLEL)),
        ("HINT_VALID", U32(LeafHint::VALID)),
        ("HINT_CELL_MASK", U32(LeafHint::CELL_MASK)),
        ("HINT_Y_SHIFT", U32(LeafHint::Y_SHIFT)),
        ("HINT_DEPTH_SHIFT", U32(LeafHint::DEPTH_SHIFT)),
        ("HINT_LABEL_SHIFT", U32(LeafHint::LABEL_SHIFT)),
        ("HINT_DEPTH_MASK", U32(LeafHint::DEPTH_MASK)),
        ("HINT_SURFACE", U32(LeafHint::SURFACE)),
        ("HINT_MAX_SURFACE_DEPTH", U32(LeafHint::MAX_SURFACE_DEPTH)),
        ("HINT_SURFACE_CELL_BITS", U32(LeafHint::SURFACE_CELL_BITS)),
        ("HINT_RECORD_DEPTH_SHIFT", U32(LeafHint::RECORD_DEPTH_SHIFT)),
        ("HINT_RECORD_MASK", U32(LeafHint::RECORD_MASK)),
        ("WORKGROUP_SIZE", U32(WORKGROUP_SIZE)),
        ("NO_INSTANCE", U32(sc::NO_INSTANCE)),
        ("INSTANCE_LIVE", U32(sc::INSTANCE_LIVE)),
        ("INSTANCE_SHOWN", U32(sc::INSTANCE_SHOWN)),
        (
            "INSTANCE_WORDS",
            U32((core::mem::size_of::<Instance>() / 4) as u32),
        ),
        (
            "BROAD_NODE_WORDS",
            U32((core::mem::size_of::<BroadNode>() / 4) as u32),
        ),
        ("BROAD_LEAF", U32(BROAD_LEAF)),
        ("BROAD_STACK", U32(sc::MAX_BROAD_DEPTH + 1)),
        ("SIDE_SLOTS", U32(SIDE_SLOTS as u32)),
        ("EMPTY_SLOT", U32(sc::EMPTY_SLOT)),
        ("SLOT_SIDE_MASK", U32(sc::SLOT_SIDE_MASK)),
        ("SLOT_REQUIRED", U32(sc::SLOT_REQUIRED)),
        ("SLOT_INSTANCE_SHIFT", U32(sc::SLOT_INSTANCE_SHIFT)),
        ("MAX_ROUNDS", U32(sc::MAX_ROUNDS)),
        ("MAX_CONTACTS", U32(sc::MAX_CONTACTS)),
        ("MAX_STALLS", U32(sc::MAX_STALLS)),
        ("MAX_SUBSTEPS", U32(sc::MAX_SUBSTEPS)),
        ("SUBSTEP_MARGIN", F32(sc::SUBSTEP_MARGIN)),
        ("SIN_POLY_C11", F32(sc::SIN_POLY[0])),
        ("SIN_POLY_C9", F32(sc::SIN_POLY[1])),
        ("SIN_POLY_C7", F32(sc::SIN_POLY[2])),
        ("SIN_POLY_C5", F32(sc::SIN_POLY[3])),
        ("SIN_POLY_C3", F32(sc::SIN_POLY[4])),
        ("SLERP_LINEAR_BELOW", F32(sc::SLERP_LINEAR_BELOW)),
        ("PATH_PAD", F32(sc::PATH_PAD)),
        ("FLAG_CRUSHED", U32(sc::FLAG_CRUSHED)),
        ("FLAG_SIDES_LOST", U32(sc::FLAG_SIDES_LOST)),
        ("FLAG_SCENE_STATUS", U32(sc::FLAG_SCENE_STATUS)),
        ("PAIR_CELL_LIMIT", F32(pairs::PAIR_CELL_LIMIT)),
        ("PAIR_HASH_NONE", U32(pairs::PAIR_HASH_NONE)),
        ("PAIR_CELL_MARGIN", F32(pairs::PAIR_CELL_MARGIN)),
        ("PAIR_SUPPORT_REACH", F32(pairs::PAIR_SUPPORT_REACH)),
        ("PAIR_WEDGED", F32(pairs::PAIR_WEDGED)),
        ("PAIR_SORT_BLOCK", U32(crate::pairs::PAIR_SORT_BLOCK)),
        ("PAIR_SORT_THREADS", U32(crate::pairs::PAIR_SORT_BLOCK / 2)),
    ]
}

/// The generated WGSL prefix: one `const` per [`shared_constants`] entry.
pub fn constants_wgsl() -> String {
    constants_wgsl_for(WORKGROUP_SIZE)
}

/// [`constants_wgsl`] with `workgroup_size` invocations per workgroup in place of
/// [`WORKGROUP_SIZE`].
fn constants_wgsl_for(workgroup_size: u32) -> String {
    let mut out = String::from(
        "// Generated from Rust by octoproxy_wgpu::shader::constants_wgsl; do not edit.\n",
    );
    for (name, value) in shared_constants() {
        let value = match name {
            "WORKGROUP_SIZE" => SharedValue::U32(workgroup_size),
            _ => value,
        };
        let line = match value {
            SharedValue::U32(v) => format!("const {name}: u32 = {v}u;\n"),
            // `{:?}` prints the shortest decimal that reads back to the same f32.
            SharedValue::F32(v) => format!("const {name}: f32 = {v:?}f;\n"),
        };
        out.push_str(&line);
    }
    out
}

/// The plain kernel's whole shader: the constants, then [`FILES`] in order.
pub fn source() -> String {
    source_upto(FILES.len())
}

/// The plain kernel's whole shader with `workgroup_size` invocations per workgroup
/// ([`crate::WgpuBackend::set_workgroup_size`]); [`source`] is the default's.
pub fn source_with_workgroup_size(workgroup_size: u32) -> String {
    let mut out = constants_wgsl_for(workgroup_size);
    append(&mut out, &FILES, FILES.len());
    out
}

/// The scene kernel's whole shader: the constants, then [`SCENE_FILES`] in order.
pub fn scene_source() -> String {
    join(&SCENE_FILES, SCENE_FILES.len())
}

/// The particle-particle pass's whole shader: the constants, then [`PAIR_FILES`] in order.
pub fn pair_source() -> String {
    join(&PAIR_FILES, PAIR_FILES.len())
}

/// The constants and the first `n` of [`FILES`] (each file needs only those before it).
pub fn source_upto(n: usize) -> String {
    join(&FILES, n)
}

/// The constants and the first `n` of `files`.
pub fn join(files: &[(&str, &str)], n: usize) -> String {
    let mut out = constants_wgsl();
    append(&mut out, files, n);
    out
}

/// Appends the first `n` of `files` to `out`, each under a line naming it.
fn append(out: &mut String, files: &[(&str, &str)], n: usize) {
    for (name, text) in &files[..n.min(files.len())] {
        out.push_str(&format!("\n// ---- {name}\n"));
        out.push_str(text);
    }
}
