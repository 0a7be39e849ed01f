//! Keeps the WGSL mirror honest: every file parses and validates with naga, every mirrored
//! struct has its Rust twin's size, alignment-driven member offsets and array stride, and
//! every shared constant has the Rust value.

use std::mem::{offset_of, size_of};

use naga::proc::Layouter;
use naga::valid::{Capabilities, ValidationFlags, Validator};
use naga::{Expression, Literal, Module, TypeInner};
use octoproxy_core::{
    BroadNode, Hit, HitEvent, Instance, PairBody, PairStep, Particle, Pose, SceneHint, SceneSlots,
    StepParams,
};
use octoproxy_wgpu::shader::{self, SharedValue, FILES, PAIR_FILES, SCENE_FILES};
use octoproxy_wgpu::{
    ChunkParams, PairPassParams, PairSortParams, PairState, RunParams, SceneParams,
};

fn parse(source: &str, what: &str) -> Module {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{what} does not parse:\n{}", e.emit_to_string(source)));
    Validator::new(ValidationFlags::all(), Capabilities::empty())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{what} does not validate:\n{}", e.emit_to_string(source)));
    module
}

fn whole() -> Module {
    parse(&shader::source(), "the joined shader")
}

fn scene_whole() -> Module {
    parse(&shader::scene_source(), "the joined scene shader")
}

fn pair_whole() -> Module {
    parse(
        &shader::pair_source(),
        "the joined particle-particle shader",
    )
}

/// A module's files (name, text) and its entry points.
type ModuleFiles = (
    &'static [(&'static str, &'static str)],
    &'static [&'static str],
);

/// The three modules, each with its files and entry points.
const MODULES: [ModuleFiles; 3] = [
    (
        &FILES,
        &[
            "step_kernel",
            "settle_kernel",
            "args_kernel",
            "march_kernel",
            "integrate_kernel",
        ],
    ),
    (&SCENE_FILES, &["scene_kernel", "scene_support_kernel"]),
    (
        &PAIR_FILES,
        &[
            "pair_reset_kernel",
            "pair_speed_kernel",
            "pair_step_kernel",
            "pair_unbias_kernel",
            "pair_key_kernel",
            "pair_sort_pass_kernel",
            "pair_sort_block_kernel",
            "pair_rank_kernel",
            "pair_gather_kernel",
            "pair_start_kernel",
            "pair_start_given_kernel",
            "pair_iterate_kernel",
            "pair_regather_kernel",
            "pair_scatter_kernel",
        ],
    ),
];

#[test]
fn every_wgsl_file_parses_and_validates_after_the_ones_it_needs() {
    for (files, entry_points) in MODULES {
        for (i, (name, _)) in files.iter().enumerate() {
            let module = parse(&shader::join(files, i + 1), name);
            assert!(
                !module.functions.is_empty() || !module.types.is_empty(),
                "{name} defines nothing"
            );
        }
        let module = parse(&shader::join(files, files.len()), "a joined module");
        let entries: Vec<&str> = module
            .entry_points
            .iter()
            .map(|e| e.name.as_str())
            .collect();
        assert_eq!(entries, entry_points);
    }
}

/// `(member name, offset)` of a WGSL struct, its size, and its alignment.
fn wgsl_struct(module: &Module, layouter: &Layouter, name: &str) -> (Vec<(String, u32)>, u32, u32) {
    let (handle, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name} in the WGSL"));
    let TypeInner::Struct { members, span } = &ty.inner else {
        panic!("{name} is not a struct")
    };
    let layout = layouter[handle];
    let members = members
        .iter()
        .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
        .collect();
    (members, *span, layout.alignment * 1u32)
}

fn layouter(module: &Module) -> Layouter {
    let mut layouter = Layouter::default();
    layouter.update(module.to_ctx()).expect("layouts");
    layouter
}

fn owned(members: &[(&str, usize)]) -> Vec<(String, u32)> {
    members
        .iter()
        .map(|(n, o)| (n.to_string(), *o as u32))
        .collect()
}

#[test]
fn particle_layout_matches_core() {
    let module = whole();
    let layouter = layouter(&module);
    let (members, size, align) = wgsl_struct(&module, &layouter, "Particle");
    let rust = owned(&[
        ("position", offset_of!(Particle, position)),
        ("side", offset_of!(Particle, side)),
        ("velocity", offset_of!(Particle, velocity)),
        ("flags", offset_of!(Particle, flags)),
    ]);
    assert_eq!(
        members, rust,
        "Particle members (name, offset): WGSL vs Rust"
    );
    assert_eq!(size as usize, size_of::<Particle>());
    // vec3<f32> aligns to 16 in WGSL: a Rust array of Particles must have the same stride.
    assert_eq!(align, 16);
    assert_eq!(size_of::<Particle>() % 16, 0);
    // The binding's runtime array: its stride is the record size.
    let (_, var) = module
        .global_variables
        .iter()
        .find(|(_, v)| v.name.as_deref() == Some("particles"))
        .expect("particles binding");
    let TypeInner::Array { stride, .. } = module.types[var.ty].inner else {
        panic!("particles is not an array")
    };
    assert_eq!(stride as usize, size_of::<Particle>());
}

#[test]
fn hint_binding_is_core_leaf_hints() {
    // core's `LeafHint { xy, z_depth_label }` is WGSL's `vec2<u32>`: two words, in that order.
    assert_eq!(offset_of!(octoproxy_core::LeafHint, xy), 0);
    assert_eq!(offset_of!(octoproxy_core::LeafHint, z_depth_label), 4);
    let module = whole();
    let (_, var) = module
        .global_variables
        .iter()
        .find(|(_, v)| v.name.as_deref() == Some("hints"))
        .expect("hints");
    let TypeInner::Array { base, stride, .. } = module.types[var.ty].inner else {
        panic!("hints is not an array")
    };
    assert_eq!(stride as usize, size_of::<octoproxy_core::LeafHint>());
    assert_eq!(stride as u64, octoproxy_wgpu::HINT_BYTES);
    assert!(matches!(
        module.types[base].inner,
        TypeInner::Vector { size: naga::VectorSize::Bi, scalar } if scalar == naga::Scalar::U32
    ));
}

#[test]
fn proxy_binding_is_the_word_array() {
    let module = whole();
    let (_, var) = module
        .global_variables
        .iter()
        .find(|(_, v)| v.name.as_deref() == Some("proxy"))
        .expect("proxy");
    let TypeInner::Array { base, stride, .. } = module.types[var.ty].inner else {
        panic!("proxy is not an array")
    };
    assert_eq!(stride, 4);
    assert!(matches!(module.types[base].inner, TypeInner::Scalar(s) if s == naga::Scalar::U32));
    let layouter = layouter(&module);
    let (members, size, _) = wgsl_struct(&module, &layouter, "NodeRecord");
    assert_eq!(members, owned(&[("a", 0), ("b", 4)]));
    assert_eq!(size as usize, size_of::<octoproxy_core::NodeRecord>());
}

#[test]
fn uniform_layouts_match_rust() {
    let module = whole();
    let layouter = layouter(&module);
    let cases: [Case; 3] = [
        (
            "StepParams",
            owned(&[
                ("gravity", offset_of!(StepParams, gravity)),
                ("dt", offset_of!(StepParams, dt)),
                ("restitution", offset_of!(StepParams, restitution)),
                ("friction", offset_of!(StepParams, friction)),
                ("radius", offset_of!(StepParams, radius)),
                ("_pad", offset_of!(StepParams, _pad)),
            ]),
            size_of::<StepParams>(),
        ),
        (
            "RunParams",
            owned(&[
                ("use_lut", offset_of!(RunParams, use_lut)),
                ("workgroup_size", offset_of!(RunParams, workgroup_size)),
                ("fold_width", offset_of!(RunParams, fold_width)),
                ("_pad2", offset_of!(RunParams, _pad2)),
            ]),
            size_of::<RunParams>(),
        ),
        (
            "ChunkParams",
            owned(&[
                ("count", offset_of!(ChunkParams, count)),
                ("first", offset_of!(ChunkParams, first)),
                ("_pad1", offset_of!(ChunkParams, _pad1)),
                ("_pad2", offset_of!(ChunkParams, _pad2)),
            ]),
            size_of::<ChunkParams>(),
        ),
    ];
    assert_layouts(&module, &layouter, &cases);
}

/// A WGSL struct, its Rust twin's (member, offset) pairs, and the twin's size.
type Case<'a> = (&'a str, Vec<(String, u32)>, usize);

/// Each struct of `cases` has its Rust twin's members at its offsets, and its size.
fn assert_layouts(module: &Module, layouter: &Layouter, cases: &[Case]) {
    for (name, rust, rust_size) in cases {
        let (members, size, _) = wgsl_struct(module, layouter, name);
        assert_eq!(
            &members, rust,
            "{name} members (name, offset): WGSL vs Rust"
        );
        assert_eq!(size as usize, *rust_size, "{name} size");
    }
}

#[test]
fn scene_layouts_match_core() {
    let module = scene_whole();
    let layouter = layouter(&module);
    let cases: [Case; 9] = [
        (
            "Pose",
            owned(&[
                ("translation", offset_of!(Pose, translation)),
                ("scale", offset_of!(Pose, scale)),
                ("rotation", offset_of!(Pose, rotation)),
            ]),
            size_of::<Pose>(),
        ),
        (
            "Instance",
            owned(&[
                ("start", offset_of!(Instance, start)),
                ("end", offset_of!(Instance, end)),
                ("proxy", offset_of!(Instance, proxy)),
                ("flags", offset_of!(Instance, flags)),
                ("leaf", offset_of!(Instance, leaf)),
                ("half_turn", offset_of!(Instance, half_turn)),
            ]),
            size_of::<Instance>(),
        ),
        (
            "BroadNode",
            owned(&[
                ("min", offset_of!(BroadNode, min)),
                ("index", offset_of!(BroadNode, index)),
                ("max", offset_of!(BroadNode, max)),
                ("kind", offset_of!(BroadNode, kind)),
            ]),
            size_of::<BroadNode>(),
        ),
        (
            "Hit",
            owned(&[
                ("instance", offset_of!(Hit, instance)),
                ("position", offset_of!(Hit, position)),
                ("normal", offset_of!(Hit, normal)),
                ("t", offset_of!(Hit, t)),
                ("speed", offset_of!(Hit, speed)),
            ]),
            size_of::<Hit>(),
        ),
        (
            "HitEvent",
            owned(&[
                ("step", offset_of!(HitEvent, step)),
                ("particle", offset_of!(HitEvent, particle)),
                ("hit", offset_of!(HitEvent, hit)),
            ]),
            size_of::<HitEvent>(),
        ),
        (
            "SceneHint",
            owned(&[
                ("hint", offset_of!(SceneHint, hint)),
                ("hint_instance", offset_of!(SceneHint, hint_instance)),
                ("first_slot", offset_of!(SceneHint, first_slot)),
            ]),
            size_of::<SceneHint>(),
        ),
        (
            "SceneSlots",
            owned(&[
                ("slots", offset_of!(SceneSlots, slots)),
                ("_pad", offset_of!(SceneSlots, _pad)),
            ]),
            size_of::<SceneSlots>(),
        ),
        (
            "SceneParams",
            owned(&[
                ("instances_at", offset_of!(SceneParams, instances_at)),
                ("nodes_at", offset_of!(SceneParams, nodes_at)),
                ("node_count", offset_of!(SceneParams, node_count)),
                ("plain", offset_of!(SceneParams, plain)),
                ("hits", offset_of!(SceneParams, hits)),
                ("event_capacity", offset_of!(SceneParams, event_capacity)),
                ("step", offset_of!(SceneParams, step)),
                ("use_lut", offset_of!(SceneParams, use_lut)),
                ("substep", offset_of!(SceneParams, substep)),
                ("substeps", offset_of!(SceneParams, substeps)),
                ("_pad0", offset_of!(SceneParams, _pad0)),
                ("_pad1", offset_of!(SceneParams, _pad1)),
            ]),
            size_of::<SceneParams>(),
        ),
        (
            "ChunkParams",
            owned(&[
                ("count", offset_of!(ChunkParams, count)),
                ("first", offset_of!(ChunkParams, first)),
                ("_pad1", offset_of!(ChunkParams, _pad1)),
                ("_pad2", offset_of!(ChunkParams, _pad2)),
            ]),
            size_of::<ChunkParams>(),
        ),
    ];
    assert_layouts(&module, &layouter, &cases);
    // The per-particle bindings: their strides are the records' sizes.
    for (binding, size) in [
        ("scene_hints", size_of::<SceneHint>()),
        ("scene_slots", size_of::<SceneSlots>()),
        ("hits", size_of::<Hit>()),
        ("particles", size_of::<Particle>()),
    ] {
        let (_, var) = module
            .global_variables
            .iter()
            .find(|(_, v)| v.name.as_deref() == Some(binding))
            .unwrap_or_else(|| panic!("no binding {binding}"));
        let TypeInner::Array { stride, .. } = module.types[var.ty].inner else {
            panic!("{binding} is not an array")
        };
        assert_eq!(stride as usize, size, "{binding} stride");
    }
    // The event buffer: after the header words, events at their size.
    let (members, _, _) = wgsl_struct(&module, &layouter, "SceneOut");
    let events = members.iter().find(|(n, _)| n == "events").expect("events");
    assert_eq!(events.1 as u64, octoproxy_wgpu::SCENE_OUT_HEADER_WORDS * 4);
    let (handle, _) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some("SceneOut"))
        .unwrap();
    let TypeInner::Struct { members, .. } = &module.types[handle].inner else {
        unreachable!()
    };
    let last = members.last().unwrap();
    let TypeInner::Array { stride, .. } = module.types[last.ty].inner else {
        panic!("events is not an array")
    };
    assert_eq!(stride as usize, size_of::<HitEvent>());
}

#[test]
fn pair_layouts_match_core() {
    let module = pair_whole();
    let layouter = layouter(&module);
    let cases: [Case; 7] = [
        (
            "PairStep",
            owned(&[
                ("gravity_h", offset_of!(PairStep, gravity_h)),
                ("h", offset_of!(PairStep, h)),
                ("up", offset_of!(PairStep, up)),
                ("inv_h", offset_of!(PairStep, inv_h)),
                ("radius", offset_of!(PairStep, radius)),
                ("diameter", offset_of!(PairStep, diameter)),
                ("inv_diameter", offset_of!(PairStep, inv_diameter)),
                ("cell", offset_of!(PairStep, cell)),
                ("inv_cell", offset_of!(PairStep, inv_cell)),
                ("mask", offset_of!(PairStep, mask)),
                ("restitution", offset_of!(PairStep, restitution)),
                ("friction", offset_of!(PairStep, friction)),
                ("relaxation", offset_of!(PairStep, relaxation)),
                ("half_stacking", offset_of!(PairStep, half_stacking)),
                ("max_candidates", offset_of!(PairStep, max_candidates)),
                ("scene_friction", offset_of!(PairStep, scene_friction)),
            ]),
            size_of::<PairStep>(),
        ),
        (
            "PairBody",
            owned(&[
                ("position", offset_of!(PairBody, position)),
                ("index", offset_of!(PairBody, index)),
                ("cell", offset_of!(PairBody, cell)),
                ("hash", offset_of!(PairBody, hash)),
            ]),
            size_of::<PairBody>(),
        ),
        (
            "PairState",
            owned(&[
                ("step", offset_of!(PairState, step)),
                ("v_max", offset_of!(PairState, v_max)),
                ("valid", offset_of!(PairState, valid)),
                ("fast_lo", offset_of!(PairState, fast_lo)),
                ("fast_hi", offset_of!(PairState, fast_hi)),
                ("capped_lo", offset_of!(PairState, capped_lo)),
                ("capped_hi", offset_of!(PairState, capped_hi)),
                ("zero", offset_of!(PairState, zero)),
                ("relaxation", offset_of!(PairState, relaxation)),
                ("deepest", offset_of!(PairState, deepest)),
                ("_pad0", offset_of!(PairState, _pad0)),
                ("_pad1", offset_of!(PairState, _pad1)),
                ("_pad2", offset_of!(PairState, _pad2)),
                ("across0", offset_of!(PairState, across0)),
                ("across1", offset_of!(PairState, across1)),
            ]),
            size_of::<PairState>(),
        ),
        (
            "PairPassParams",
            owned(&[
                ("count", offset_of!(PairPassParams, count)),
                ("table", offset_of!(PairPassParams, table)),
                ("_pad0", offset_of!(PairPassParams, _pad0)),
                ("_pad1", offset_of!(PairPassParams, _pad1)),
            ]),
            size_of::<PairPassParams>(),
        ),
        (
            "PairSortParams",
            owned(&[
                ("k", offset_of!(PairSortParams, k)),
                ("j", offset_of!(PairSortParams, j)),
                ("threads", offset_of!(PairSortParams, threads)),
                ("block", offset_of!(PairSortParams, block)),
                ("k_last", offset_of!(PairSortParams, k_last)),
                ("_pad0", offset_of!(PairSortParams, _pad0)),
                ("_pad1", offset_of!(PairSortParams, _pad1)),
                ("_pad2", offset_of!(PairSortParams, _pad2)),
            ]),
            size_of::<PairSortParams>(),
        ),
        (
            "ChunkParams",
            owned(&[
                ("count", offset_of!(ChunkParams, count)),
                ("first", offset_of!(ChunkParams, first)),
                ("_pad1", offset_of!(ChunkParams, _pad1)),
                ("_pad2", offset_of!(ChunkParams, _pad2)),
            ]),
            size_of::<ChunkParams>(),
        ),
        (
            "Particle",
            owned(&[
                ("position", offset_of!(Particle, position)),
                ("side", offset_of!(Particle, side)),
                ("velocity", offset_of!(Particle, velocity)),
                ("flags", offset_of!(Particle, flags)),
            ]),
            size_of::<Particle>(),
        ),
    ];
    assert_layouts(&module, &layouter, &cases);
    // The pass's arrays: their strides are core's records' sizes (keys and ranges are
    // `[u32; 2]`, velocities `PairVelocity`).
    for (binding, size) in [
        ("particles", size_of::<Particle>()),
        ("pair_keys", size_of::<[u32; 2]>()),
        ("pair_rank", size_of::<u32>()),
        ("pair_bodies", size_of::<PairBody>()),
        ("pair_vel", size_of::<octoproxy_core::PairVelocity>()),
        ("pair_vel_next", size_of::<octoproxy_core::PairVelocity>()),
        ("pair_ranges", size_of::<[u32; 2]>()),
        ("pair_supports", size_of::<[f32; 4]>()),
        ("pair_hints", size_of::<octoproxy_core::LeafHint>()),
    ] {
        let (_, var) = module
            .global_variables
            .iter()
            .find(|(_, v)| v.name.as_deref() == Some(binding))
            .unwrap_or_else(|| panic!("no binding {binding}"));
        let TypeInner::Array { stride, .. } = module.types[var.ty].inner else {
            panic!("{binding} is not an array")
        };
        assert_eq!(stride as usize, size, "{binding} stride");
    }
}

#[test]
fn shared_constants_have_the_rust_values() {
    for module in [whole(), scene_whole(), pair_whole()] {
        shared_constants_of(&module);
    }
}

fn shared_constants_of(module: &Module) {
    let mut checked = 0;
    for (name, value) in shader::shared_constants() {
        let (_, constant) = module
            .constants
            .iter()
            .find(|(_, c)| c.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("constant {name} missing from the WGSL"));
        let found = match module.global_expressions[constant.init] {
            Expression::Literal(Literal::U32(v)) => SharedValue::U32(v),
            Expression::Literal(Literal::F32(v)) => SharedValue::F32(v),
            ref other => panic!("{name} is not a literal: {other:?}"),
        };
        match (found, value) {
            // Bit equality: the WGSL literal must read back to the very same f32.
            (SharedValue::F32(a), SharedValue::F32(b)) => {
                assert_eq!(a.to_bits(), b.to_bits(), "{name}")
            }
            (a, b) => assert_eq!(a, b, "{name}"),
        }
        checked += 1;
    }
    assert!(checked >= 40, "only {checked} constants checked");
    // The hand-written files define no numeric constants of their own: all come from Rust.
    for (name, text) in FILES.iter().chain(&SCENE_FILES).chain(&PAIR_FILES) {
        assert!(
            !text.contains("\nconst "),
            "{name} defines its own const; generate it from Rust instead"
        );
    }
}

/// The Rust twin of a WGSL function, or why it has none.
enum Twin {
    /// The Rust source file (under `core/src/`) and the function's path there: a free
    /// function, or `Type::method`.
    Rust(&'static str, &'static str),
    /// No twin, and why.
    None(&'static str),
}
use Twin::None as NoTwin;
use Twin::Rust;

/// Every function and entry point of every `.wgsl` file, with its Rust twin. A WGSL function
/// without a row fails `every_wgsl_function_has_a_row`, and so does a row whose function is
/// gone, or whose Rust twin is.
const TWINS: &[(&str, &str, Twin)] = &[
    // format.wgsl
    ("format.wgsl", "load_header", NoTwin("decodes the header of the proxy in use; Rust decodes it once per proxy, in ProxyView::new, and passes the view")),
    ("format.wgsl", "node_record", Rust("view.rs", "ProxyView::nodes")),
    ("format.wgsl", "is_leaf", Rust("format.rs", "NodeRecord::is_leaf")),
    ("format.wgsl", "plane_offset", Rust("format.rs", "NodeRecord::plane_offset")),
    ("format.wgsl", "clearance", Rust("format.rs", "NodeRecord::clearance")),
    ("format.wgsl", "first_child", Rust("format.rs", "NodeRecord::first_child")),
    ("format.wgsl", "child_mask", Rust("format.rs", "NodeRecord::child_mask")),
    ("format.wgsl", "label_bits", Rust("format.rs", "NodeRecord::label_bits")),
    ("format.wgsl", "child_index", Rust("format.rs", "NodeRecord::child_index")),
    ("format.wgsl", "is_two_sided", Rust("format.rs", "NodeRecord::is_two_sided")),
    ("format.wgsl", "normal", Rust("format.rs", "NodeRecord::normal")),
    // WGSL's own `sign` is a builtin, and gives 0 for 0.
    ("format.wgsl", "sign_nonneg", Rust("format.rs", "sign")),
    ("format.wgsl", "dot3", NoTwin("glam's Vec3::dot, its order of operations spelled out")),
    ("format.wgsl", "decode_normal", Rust("format.rs", "decode_normal")),
    ("format.wgsl", "grid_plane", Rust("format.rs", "grid_plane")),
    ("format.wgsl", "is_finite", NoTwin("f32::is_finite, as a bit test that holds whatever a driver assumes about NaN")),
    ("format.wgsl", "is_finite3", NoTwin("glam's Vec3::is_finite")),
    ("format.wgsl", "infinity", NoTwin("f32::INFINITY: WGSL has no infinite literal")),
    // query.wgsl
    ("query.wgsl", "upper", Rust("query.rs", "upper")),
    ("query.wgsl", "plane", Rust("view.rs", "ProxyView::plane")),
    ("query.wgsl", "root_aabb", Rust("query.rs", "ProxyView::root_aabb")),
    ("query.wgsl", "cell_aabb", Rust("query.rs", "ProxyView::cell_aabb")),
    ("query.wgsl", "root_contains", Rust("query.rs", "ProxyView::root_contains")),
    ("query.wgsl", "surface_leaf", Rust("query.rs", "ProxyView::surface_leaf")),
    ("query.wgsl", "empty_leaf", Rust("query.rs", "ProxyView::empty_leaf")),
    ("query.wgsl", "cell_at_depth", Rust("query.rs", "ProxyView::cell_at_depth")),
    ("query.wgsl", "locate_inside", Rust("query.rs", "ProxyView::locate_inside")),
    ("query.wgsl", "locate_leaf_toward", Rust("query.rs", "ProxyView::locate_leaf_toward")),
    ("query.wgsl", "locate_next", Rust("query.rs", "ProxyView::locate_next")),
    ("query.wgsl", "locate_in_cell", Rust("query.rs", "ProxyView::locate_in_cell")),
    ("query.wgsl", "descend", Rust("query.rs", "ProxyView::descend")),
    // step.wgsl
    ("step.wgsl", "respond", Rust("step.rs", "respond")),
    ("step.wgsl", "pinch", Rust("step.rs", "pinch")),
    ("step.wgsl", "face_normal", Rust("step.rs", "face_normal")),
    ("step.wgsl", "entry_faces", Rust("step.rs", "entry_faces")),
    ("step.wgsl", "exit_box", Rust("step.rs", "exit_box")),
    ("step.wgsl", "enter_box", Rust("step.rs", "enter_box")),
    ("step.wgsl", "side_of", Rust("step.rs", "side_of")),
    ("step.wgsl", "leaf_hint_of", Rust("step.rs", "LeafHint::of")),
    ("step.wgsl", "leaf_hint_leaf", Rust("step.rs", "LeafHint::leaf")),
    ("step.wgsl", "max_leaves_per_step", Rust("step.rs", "max_leaves_per_step")),
    ("step.wgsl", "collisions", Rust("particle.rs", "Particle::collisions")),
    ("step.wgsl", "step_particle_hinted", Rust("step.rs", "step_particle_hinted")),
    ("step.wgsl", "settle_leaving_root", Rust("step.rs", "settle_leaving_root")),
    ("step.wgsl", "settle_in_hinted_leaf", Rust("step.rs", "settle_in_hinted_leaf")),
    ("step.wgsl", "settle_on_plane", Rust("step.rs", "settle_on_plane")),
    ("step.wgsl", "start_beside_shell", Rust("step.rs", "start_beside_shell")),
    ("step.wgsl", "start_march", Rust("step.rs", "start_march")),
    ("step.wgsl", "stop_at_leaf_bound", Rust("step.rs", "stop_at_leaf_bound")),
    ("step.wgsl", "find_next_leaf", Rust("step.rs", "find_next_leaf")),
    ("step.wgsl", "enter_root", Rust("step.rs", "enter_root")),
    ("step.wgsl", "slide_off_solid_face", Rust("step.rs", "slide_off_solid_face")),
    ("step.wgsl", "enter_empty_leaf", Rust("step.rs", "enter_empty_leaf")),
    ("step.wgsl", "block_at_shell", Rust("step.rs", "block_at_shell")),
    ("step.wgsl", "enter_surface_leaf", Rust("step.rs", "enter_surface_leaf")),
    ("step.wgsl", "slab_entry", Rust("step.rs", "slab_entry")),
    ("step.wgsl", "walk_in_slab", Rust("step.rs", "walk_in_slab")),
    ("step.wgsl", "move_in_box", Rust("step.rs", "move_in_box")),
    ("step.wgsl", "collision_normal", Rust("step.rs", "collision_normal")),
    ("step.wgsl", "reach_plane", Rust("step.rs", "reach_plane")),
    ("step.wgsl", "collide", Rust("step.rs", "collide")),
    ("step.wgsl", "walk_in_cage", Rust("step.rs", "walk_in_cage")),
    ("step.wgsl", "side_exit", Rust("particle.rs", "side_exit")),
    ("step.wgsl", "next_float", Rust("step.rs", "next_float")),
    ("step.wgsl", "strictly_inside", Rust("step.rs", "strictly_inside")),
    ("step.wgsl", "travel_through_leaf", Rust("step.rs", "travel_through_leaf")),
    ("step.wgsl", "finish_march", Rust("step.rs", "finish_march")),
    ("step.wgsl", "march_after", Rust("step.rs", "march_after")),
    ("step.wgsl", "march_hinted", Rust("step.rs", "march_hinted")),
    // observe_none.wgsl (the plain kernel's) and observe.wgsl (the scene kernel's)
    ("observe_none.wgsl", "observe_hit", Rust("step.rs", "MarchObserver::hit")),
    ("observe.wgsl", "observe_hit", Rust("scene.rs", "HitObserver::hit")),
    ("observe.wgsl", "observe", Rust("scene.rs", "HitObserver::new")),
    ("observe.wgsl", "push_event", Rust("scene.rs", "HitEvents::hit")),
    ("observe.wgsl", "count_crushed", NoTwin("a 64-bit count in two atomic words; the CPU adds u64s (step_one's report)")),
    ("observe.wgsl", "count_sides_lost", NoTwin("a 64-bit count in two atomic words; the CPU adds u64s (step_one's report)")),
    ("observe.wgsl", "count_lost_event", NoTwin("a 64-bit count in two atomic words; the CPU adds u64s (CpuEvents)")),
    // pose.wgsl
    ("pose.wgsl", "use_proxy", NoTwin("loads the header of the proxy an instance names; Rust indexes the scene's ProxyViews")),
    ("pose.wgsl", "load_pose", NoTwin("a Pose from the scene buffer's words; Rust reads the Pod slice")),
    ("pose.wgsl", "load_instance", NoTwin("an Instance from the scene buffer's words; Rust reads the Pod slice")),
    ("pose.wgsl", "load_broad_node", NoTwin("a BroadNode from the scene buffer's words; Rust reads the Pod slice")),
    ("pose.wgsl", "instance_count", NoTwin("the instances in the scene buffer's words; Rust has the slice's length")),
    ("pose.wgsl", "instance_is_active", Rust("scene.rs", "Instance::is_active")),
    ("pose.wgsl", "hit_in_whole_step", Rust("scene.rs", "Hit::in_whole_step")),
    ("pose.wgsl", "plus_zero", Rust("scene.rs", "plus_zero")),
    ("pose.wgsl", "max_of", Rust("scene.rs", "max_of")),
    ("scene.wgsl", "chord_per_length", Rust("scene.rs", "chord_per_length")),
    ("pose.wgsl", "min_of", Rust("scene.rs", "min_of")),
    ("pose.wgsl", "vmax", NoTwin("glam's Vec3::max")),
    ("pose.wgsl", "vmin", NoTwin("glam's Vec3::min")),
    ("pose.wgsl", "max_element", NoTwin("glam's Vec3::max_element")),
    ("pose.wgsl", "length3", NoTwin("glam's Vec3::length: sqrt of dot3")),
    ("pose.wgsl", "ulp", Rust("view.rs", "ulp")),
    ("pose.wgsl", "wide_length3", Rust("view.rs", "wide_length")),
    ("pose.wgsl", "rotate", Rust("scene.rs", "rotate")),
    ("pose.wgsl", "conjugate", Rust("scene.rs", "conjugate")),
    ("pose.wgsl", "sin_poly", Rust("scene.rs", "sin_poly")),
    ("pose.wgsl", "pose_to_world", Rust("scene.rs", "Pose::to_world")),
    ("pose.wgsl", "pose_to_local", Rust("scene.rs", "Pose::to_local")),
    ("pose.wgsl", "pose_vector_to_world", Rust("scene.rs", "Pose::vector_to_world")),
    ("pose.wgsl", "pose_vector_to_local", Rust("scene.rs", "Pose::vector_to_local")),
    ("pose.wgsl", "pose_normal_to_world", Rust("scene.rs", "Pose::normal_to_world")),
    ("pose.wgsl", "same_pose", Rust("scene.rs", "pose_words")),
    ("pose.wgsl", "identity_pose", NoTwin("Pose::IDENTITY: WGSL has no struct constants")),
    ("pose.wgsl", "instance_is_static", Rust("scene.rs", "Instance::is_static")),
    ("pose.wgsl", "instance_pose_at", Rust("scene.rs", "Instance::pose_at")),
    ("pose.wgsl", "hit_frame_whole_step", Rust("scene.rs", "HitFrame::whole_step")),
    ("pose.wgsl", "hit_frame_hit", Rust("scene.rs", "HitFrame::hit")),
    ("pose.wgsl", "no_hit", NoTwin("Hit::NONE: WGSL has no struct constants")),
    ("pose.wgsl", "hit_position", NoTwin("Vec3::from_array(hit.position)")),
    ("pose.wgsl", "hit_normal", NoTwin("Vec3::from_array(hit.normal)")),
    // scene.wgsl
    ("scene.wgsl", "scene_sides_join", Rust("scene.rs", "SceneSides::join")),
    ("scene.wgsl", "scene_sides_split", Rust("scene.rs", "SceneSides::split")),
    ("scene.wgsl", "commit", Rust("scene.rs", "commit")),
    ("scene.wgsl", "optional_slots", Rust("scene.rs", "optional")),
    ("scene.wgsl", "slot_side", Rust("scene.rs", "slot_side")),
    ("scene.wgsl", "kept_side", Rust("scene.rs", "kept_side")),
    ("scene.wgsl", "first_side", Rust("scene.rs", "first_side")),
    ("scene.wgsl", "broad_walk_new", Rust("scene.rs", "BroadWalk::new")),
    ("scene.wgsl", "broad_walk_next", Rust("scene.rs", "BroadWalk::next")),
    ("scene.wgsl", "count_candidates", Rust("scene.rs", "SceneView::count_candidates")),
    ("scene.wgsl", "finest_leaf_size", Rust("view.rs", "ProxyView::finest_leaf_size")),
    ("scene.wgsl", "local_radius", Rust("scene.rs", "local_radius")),
    ("scene.wgsl", "initial_side", Rust("step.rs", "initial_side")),
    ("scene.wgsl", "substeps", Rust("scene.rs", "substeps")),
    ("scene.wgsl", "must_keep", Rust("scene.rs", "must_keep")),
    ("scene.wgsl", "derived_side", Rust("scene.rs", "derived_side")),
    ("scene.wgsl", "march_in_frame", Rust("scene.rs", "march_in_frame")),
    ("scene.wgsl", "step_particle_scene", Rust("scene.rs", "step_particle_scene")),
    ("scene.wgsl", "step_plain", Rust("scene.rs", "step_plain")),
    ("scene.wgsl", "step_particle_scene_general", Rust("scene.rs", "step_particle_scene_general")),
    ("scene.wgsl", "step_near_one_static", Rust("scene.rs", "step_near_one_static")),
    ("scene.wgsl", "ride_is_clear", Rust("scene.rs", "ride_is_clear")),
    ("scene.wgsl", "side_for", Rust("scene.rs", "step_in_rounds")),
    ("scene.wgsl", "collided_in", Rust("scene.rs", "step_in_rounds")),
    ("scene.wgsl", "step_in_rounds", Rust("scene.rs", "step_in_rounds")),
    // scene_kernel.wgsl
    ("scene_kernel.wgsl", "particle_index", NoTwin("a particle's index from the dispatch grid; the CPU backend iterates")),
    ("scene_kernel.wgsl", "scene_kernel", NoTwin("entry point: one scene step of one particle; CpuBackend's loop over particles (step_one)")),
    ("scene_kernel.wgsl", "scene_support_kernel", NoTwin("entry point: pair_support_scene of one particle, for pair_start_given_kernel; CpuBackend calls pair_start_scene")),
    // pairs.wgsl
    ("pairs.wgsl", "pair_cell_edge", Rust("pairs.rs", "pair_cell_edge")),
    ("pairs.wgsl", "pair_is_fast", Rust("pairs.rs", "pair_is_fast")),
    ("pairs.wgsl", "pair_prepare", Rust("pairs.rs", "pair_prepare")),
    ("pairs.wgsl", "pair_cell", Rust("pairs.rs", "pair_cell")),
    ("pairs.wgsl", "pair_height", Rust("pairs.rs", "pair_height")),
    ("pairs.wgsl", "pair_column_key", Rust("pairs.rs", "pair_column_key")),
    ("pairs.wgsl", "pair_column_slot", Rust("pairs.rs", "pair_column_slot")),
    ("pairs.wgsl", "region_mix", Rust("pairs.rs", "region_mix")),
    ("support.wgsl", "pair_support", Rust("pairs.rs", "pair_support")),
    ("scene.wgsl", "pair_support_scene", Rust("pairs.rs", "pair_support_scene")),
    ("pairs.wgsl", "pair_start", Rust("pairs.rs", "pair_start")),
    ("pairs.wgsl", "pair_start_with", Rust("pairs.rs", "pair_start_with")),
    ("pairs.wgsl", "pair_hash", Rust("pairs.rs", "pair_hash")),
    ("pairs.wgsl", "pair_range_marks", Rust("pairs.rs", "pair_range_marks")),
    ("pairs.wgsl", "pair_target", Rust("pairs.rs", "pair_target")),
    ("pairs.wgsl", "pair_weight", Rust("pairs.rs", "pair_weight")),
    ("pairs.wgsl", "pair_free", Rust("pairs.rs", "pair_free")),
    ("pairs.wgsl", "pair_impulse", Rust("pairs.rs", "pair_impulse")),
    ("pairs.wgsl", "pair_velocity", Rust("pairs.rs", "pair_velocity")),
    // pairs_kernel.wgsl
    ("pairs_kernel.wgsl", "particle_index", NoTwin("a particle's index from the dispatch grid; the CPU backend iterates")),
    ("pairs_kernel.wgsl", "count_fast", NoTwin("a 64-bit count in two atomic words; the CPU adds u64s (CpuBackend::step_pairs)")),
    ("pairs_kernel.wgsl", "count_capped", NoTwin("a 64-bit count in two atomic words; the CPU adds u64s (PairBuffers::substep)")),
    ("pairs_kernel.wgsl", "key_less", NoTwin("the order of core's [hash, index] keys: Rust compares the arrays (the CPU backend one u64 per key)")),
    ("pairs_kernel.wgsl", "pair_reset_kernel", NoTwin("entry point: the table cleared (collide_pairs' ranges.fill), the largest speed and the valid count zeroed")),
    ("pairs_kernel.wgsl", "pair_speed_kernel", NoTwin("entry point: pair_max_speed and pair_fast_count, as atomics (the CPU backend's reduce in step_pairs)")),
    ("pairs_kernel.wgsl", "pair_step_kernel", NoTwin("entry point: PairStep::new's cell and inv_cell from the largest speed, on the GPU (no read-back)")),
    ("pairs_kernel.wgsl", "pair_key_kernel", NoTwin("entry point: collide_pairs' keys")),
    ("pairs_kernel.wgsl", "sort_swaps", NoTwin("a bitonic sort's compare-exchange; the CPU sorts with sort_unstable: the order is total, so the array is the same")),
    ("pairs_kernel.wgsl", "pair_sort_pass_kernel", NoTwin("entry point: a pass of the bitonic sort over all the keys (the CPU's par_sort_unstable)")),
    ("pairs_kernel.wgsl", "pair_sort_block_kernel", NoTwin("entry point: the bitonic sort's stages within a block, in workgroup memory (the CPU's par_sort_unstable)")),
    ("pairs_kernel.wgsl", "pair_rank_kernel", NoTwin("entry point: collide_pairs' range marks and valid count, and each particle's place (the CPU backend's rank)")),
    ("pairs_kernel.wgsl", "pair_gather_kernel", NoTwin("entry point: collide_pairs' bodies in sorted order")),
    ("pairs_kernel.wgsl", "pair_start_given_kernel", NoTwin("entry point: pair_start_scene's pair_start_with in sorted order, with the supports scene_support_kernel found")),
    ("pairs_kernel.wgsl", "pair_start_kernel", NoTwin("entry point: collide_pairs' pair_start in sorted order, from each particle and its hint")),
    ("pairs_kernel.wgsl", "pair_iterate_kernel", NoTwin("entry point: one Jacobi iteration, collide_pairs' loop body over k")),
    ("pairs_kernel.wgsl", "pair_scatter_kernel", NoTwin("entry point: collide_pairs' (and debias_pairs') velocities back to the valid particles")),
    ("pairs_kernel.wgsl", "pair_unbias_kernel", NoTwin("entry point: PairStep::unbiased on the GPU's state, before the debiasing iterations")),
    ("pairs_kernel.wgsl", "pair_regather_kernel", NoTwin("entry point: debias_pairs' marched velocities in sorted order")),
    // kernel.wgsl
    ("kernel.wgsl", "particle_index", NoTwin("a particle's index from the dispatch grid; the CPU backend iterates")),
    ("kernel.wgsl", "step_kernel", NoTwin("entry point: one step of one particle; CpuBackend's loop over particles")),
    ("kernel.wgsl", "settle_kernel", NoTwin("entry point: the split step's first dispatch, step_particle_hinted's first settle or a place in the queue; CpuBackend steps each particle whole")),
    ("kernel.wgsl", "args_kernel", NoTwin("entry point: the split step's indirect dispatch size from the queue's length; nothing to size on the CPU")),
    ("kernel.wgsl", "march_kernel", NoTwin("entry point: the split step's queued particles, each stepped by step_particle_hinted as step_kernel does")),
    ("kernel.wgsl", "integrate_kernel", NoTwin("entry point: the bench's floor, integration without collision")),
];

/// The functions of core's step and query modules that run on the host only, and why. With
/// the twins above, every function of `step.rs` and `query.rs` has a row.
const HOST_ONLY: &[(&str, &str, &str)] = &[
    ("step.rs", "fmt", "ParamError's Display: errors are the host's"),
    ("pairs.rs", "pair_start_scene", "pair_start_with of pair_support_scene: on the GPU two kernels, scene_support_kernel and pair_start_given_kernel, since the pass's module holds no scene"),
    ("step.rs", "check_radius", "the host checks the particles' radius against the proxy's before stepping"),
    ("scene.rs", "check_radius", "SceneView::check_radius: the host checks every instance's radius before stepping"),
    ("scene.rs", "plain_first_slot", "step_plain's first slot, made apart for the CPU backend, which steps a one-proxy static scene as the plain step and makes the slots only when asked for them; step_plain's twin makes it inline"),
    ("query.rs", "surface_box", "ProxyView::surface_box: the host's scene check (how instances' shells overlap)"),
    ("step.rs", "default", "StepParams::default: the host fills the uniform"),
    ("step.rs", "validate", "StepParams::validate: the host checks parameters before uploading them"),
    ("step.rs", "step_particle", "the unhinted entry point; the GPU always keeps hints (step_particle_hinted with none is the same step)"),
    ("step.rs", "march_from_hint", "keeps the march and settle_on_plane out of line of the hot settles on the CPU; WGSL's step_particle_hinted decodes the hint, then calls settle_on_plane, then march_hinted"),
    ("step.rs", "march", "march_after with no leaf collided in, for the host's unhinted entry points (step_particle, traced, counted); WGSL's step_particle_hinted goes to march_hinted"),
    ("step.rs", "step_particle_traced", "host-only: ground-truth checks of the path"),
    ("step.rs", "step_hinted_observed", "step_particle_hinted reporting collisions to an observer; WGSL's step_particle_hinted always reports them, to observe_hit (nothing in the plain kernel)"),
    ("step.rs", "step_particle_counted", "host-only: tests count the rare branches"),
    ("step.rs", "step_particle_profiled", "host-only: the bench's profile of kinds of step"),
    ("step.rs", "finished", "MarchObserver: the profile's count of leaves; WGSL has no observer"),
    ("step.rs", "name", "StepKind, for the bench"),
    ("step.rs", "add", "MarchCounts, for tests"),
    ("step.rs", "index", "MarchCounts, for tests"),
    ("step.rs", "piece", "the march's observers' path pieces: for ground truth on the host; WGSL observes only collisions"),
    ("step.rs", "branch", "the march's observers' rare branches: for tests on the host; WGSL observes only collisions"),
    ("step.rs", "clamp", "f32::clamp without its assertion; WGSL's is the builtin clamp"),
    ("step.rs", "finish_caged", "finish_march out of line for a step that ends in its cage, to keep the CPU's march small; WGSL calls finish_march"),
    ("query.rs", "key", "LeafInfo::key: the baker's and the tests' leaf identity"),
    ("query.rs", "cell_box", "cell_aabb in SIMD vectors for the settled step; the same floats as WGSL's cell_aabb"),
    ("query.rs", "locate_leaf", "a checked public query; the step uses locate_inside, the pass's support locate_leaf_toward"),
    ("query.rs", "locate_leaf_from", "a checked public query; the step uses locate_next"),
    ("scene.rs", "default", "Default impls: the host fills the buffers"),
    ("scene.rs", "fmt", "SceneError's Display and SceneView's Debug: the host's"),
    ("scene.rs", "instance", "SceneError::instance: which instance an error names, for the host's messages"),
    ("scene.rs", "trace_ride", "a ride's chords for the CPU harness's trace (PathTrace); the GPU traces no paths"),
    ("scene.rs", "half_turn", "the host computes an instance's half turn once (Instance::new); the step reads it"),
    ("scene.rs", "is_valid", "Pose::is_valid: SceneView::new's check, on the host"),
    ("scene.rs", "swept_box", "the host builds the broad phase's boxes"),
    ("scene.rs", "swept_box_of", "the host builds the broad phase's boxes"),
    ("scene.rs", "aabb", "BroadNode's box, for the host's validation"),
    ("scene.rs", "max_turn", "SceneView::new's check, on the host"),
    ("scene.rs", "contains", "SceneView::new's check, on the host"),
    ("scene.rs", "plain_proxy", "the host computes it and passes the instance in SceneParams::plain"),
    ("scene.rs", "proxies", "SceneView accessors, for the host"),
    ("scene.rs", "instances", "SceneView accessors, for the host"),
    ("scene.rs", "nodes", "SceneView accessors, for the host"),
    ("scene.rs", "for_each_candidate", "a closure over BroadWalk; WGSL loops over broad_walk_next"),
    ("scene.rs", "next_leaf", "BroadWalk::next's leaf node, for Nearby; broad_walk_next tests and returns the instance in one"),
    ("scene.rs", "meets", "the walk's box test, shared by BroadWalk::next_leaf and Nearby's filter; inline in broad_walk_next"),
    ("scene.rs", "count_nearby", "count_candidates keeping the leaves found (Nearby): the CPU's later queries filter them; WGSL walks each time, with the same answers"),
    ("scene.rs", "for_each_nearby", "for_each_candidate from Nearby; WGSL walks each time, with the same answers"),
    ("scene.rs", "count_in_nearby", "count_candidates from Nearby; WGSL walks each time, with the same answers"),
    ("scene.rs", "holds", "Nearby::holds: whether the kept leaves answer a query; WGSL walks each time"),
    ("scene.rs", "grid_sizes", "SceneView::grid_sizes: the host sizes the CPU's grid over the broad phase; WGSL walks"),
    ("scene.rs", "with_grid", "SceneView::with_grid: the CPU's grid over the broad phase for a step's first query; WGSL walks (the same answers)"),
    ("scene.rs", "of", "GridShape::of: the CPU's grid's cells"),
    ("scene.rs", "cells", "GridShape::cells: the CPU's grid's cells"),
    ("scene.rs", "grown", "GridShape::grown: a cell of the CPU's grid, grown by a quarter"),
    ("scene.rs", "index", "GridShape::index: a cell of the CPU's grid"),
    ("scene.rs", "cell_of", "GridShape::cell_of: the CPU's grid's cell of a point"),
    ("scene.rs", "for_each_entry", "GridShape::for_each_entry: the CPU's grid's lists, built on the host"),
    ("scene.rs", "cell_holding", "BroadGrid::cell_holding: the CPU's grid's list for a query; WGSL walks"),
    ("scene.rs", "set_side", "SceneSides::set_side: the host sets starting sides"),
    ("scene.rs", "iter", "SceneSides::iter: the host reads sides"),
    ("scene.rs", "side_of", "SceneSides::side_of: the host reads sides"),
    ("scene.rs", "record", "HitObserver::record: WGSL reads observer.last"),
    ("scene.rs", "piece", "path pieces for ground truth, on the host"),
    ("scene.rs", "branch", "path pieces for ground truth, on the host"),
    ("scene.rs", "step_particle_scene_traced", "host-only: ground-truth checks of the path"),
    ("pairs.rs", "default", "PairParams::default: the host's"),
    ("pairs.rs", "fmt", "PairParamError's Display: errors are the host's"),
    ("pairs.rs", "validate", "PairParams::validate: the host checks parameters before stepping"),
    ("pairs.rs", "pair_substeps", "the host splits each step into substeps and records them"),
    ("pairs.rs", "pair_substeps_for", "the host chooses each step's substeps from the largest speed it reads back"),
    ("pairs.rs", "pair_substep_range", "the host checks a scene step's substep count"),
    ("pairs.rs", "pair_probe_speed", "a reduction: pair_speed_kernel's atomicMax over pair_prepare's speeds with a zero substep (no gravity), read back by the host"),
    ("pairs.rs", "pair_up", "the host writes PairStep::up (PairStep::new's)"),
    ("pairs.rs", "pair_across", "the host writes the probe's vectors across gravity into PairState::across0 and across1"),
    ("pairs.rs", "pair_column_table_size", "the host sizes the probe's columns buffer"),
    ("pairs.rs", "of_all", "PairProbe::of_all: the probe on one thread; the GPU runs pair_reset_kernel and pair_speed_kernel with a zero substep (each particle's column counted in the columns buffer by compare-exchange, the most kept by atomicMax), read back by the host"),
    ("pairs.rs", "pair_iterations_for", "the host chooses each step's iterations from the probe it reads back and records that many pair_iterate_kernel dispatches"),
    ("pairs.rs", "pair_table_size", "the host sizes the table and writes PairStep::mask"),
    ("pairs.rs", "new", "PairStep::new: the host writes every field but the cell; pair_step_kernel computes cell and inv_cell from the GPU's largest speed with pair_cell_edge, as new does. PairSum::new: pair_velocity's start, inlined in pairs.wgsl's"),
    ("pairs.rs", "collide_pairs", "the pass on one thread; the GPU runs its stages as kernels (pairs_kernel.wgsl), the CPU backend as rayon loops"),
    ("pairs.rs", "debias_pairs", "the debiasing iterations on one thread; the GPU runs pair_unbias_kernel, pair_regather_kernel, pair_iterate_kernel and pair_scatter_kernel, the CPU backend PairBuffers::debias"),
    ("pairs.rs", "unbiased", "PairStep::unbiased: pair_unbias_kernel writes its relaxation of zero into the GPU's state, pair_step_kernel restores PairState::relaxation"),
    ("pairs.rs", "holds", "PairScratch::holds: collide_pairs' and debias_pairs' check of the caller's scratch, on the host"),
    ("pairs.rs", "iterate", "PairScratch::iterate: the serial iterations of collide_pairs and debias_pairs; the GPU runs pair_iterate_kernel once per iteration"),
    ("pairs.rs", "pair_max_speed", "a reduction: pair_speed_kernel's atomicMax over pair_prepare's speeds"),
    ("pairs.rs", "pair_fast_count", "a reduction: pair_speed_kernel's count over pair_is_fast"),
    ("pairs.rs", "pair_candidates", "pair_velocity's neighbour loop, which pairs.wgsl's pair_velocity inlines; the CPU backend lists a substep's candidates once with it"),
    ("pairs.rs", "pair_neighbourhood", "pair_candidates' visit of the 27 cells, inlined in pairs.wgsl's pair_velocity; the CPU backend gathers it once per cell and filters it for each of the cell's particles"),
    ("pairs.rs", "pair_neighbourhood_where", "pair_neighbourhood passing over the buckets of cells a bitmap says are empty (the same entries and cap count; the CPU backend's listing); the GPU visits every bucket"),
    ("pairs.rs", "neighbourhood_hashes", "pair_neighbourhood's 27 cells hashed from per-axis parts: pairs.wgsl's pair_velocity calls pair_hash for each cell, the same values (a core test compares them)"),
    ("pairs.rs", "cell_place", "pair_hash's place of a cell in its region's run, one axis's bits: pairs.wgsl's pair_hash writes the Morton code bit by bit, the same bits (a core test compares them)"),
    ("pairs.rs", "pair_in_reach", "pair_candidates' filter (not itself, closer than the cell edge), inlined in pairs.wgsl's pair_velocity"),
    ("pairs.rs", "pair_velocity_listed", "pair_velocity from candidates listed once a substep (the CPU backend's); the GPU searches in each iteration"),
    ("pairs.rs", "pair_geometry", "pair_impulse's first half (normal, gap, share: positions only), inlined in pairs.wgsl's pair_impulse; the CPU backend keeps it per listed candidate"),
    ("pairs.rs", "pair_response", "pair_impulse's second half (from the velocities), inlined in pairs.wgsl's pair_impulse"),
    ("pairs.rs", "add", "PairSum::add: pair_velocity's sum of one contact, inlined in pairs.wgsl's loop"),
    ("pairs.rs", "finish", "PairSum::finish: pair_velocity's mean and support response, inlined at the end of pairs.wgsl's"),
];

/// core's source files, by name.
fn rust_source(file: &str) -> &'static str {
    match file {
        "step.rs" => include_str!("../../core/src/step.rs"),
        "query.rs" => include_str!("../../core/src/query.rs"),
        "format.rs" => include_str!("../../core/src/format.rs"),
        "view.rs" => include_str!("../../core/src/view.rs"),
        "particle.rs" => include_str!("../../core/src/particle.rs"),
        "scene.rs" => rust_code(include_str!("../../core/src/scene.rs")),
        "pairs.rs" => rust_code(include_str!("../../core/src/pairs.rs")),
        other => panic!("no core source {other} in this test"),
    }
}

/// A source without its unit tests (`#[cfg(test)] mod tests` at its end).
fn rust_code(source: &'static str) -> &'static str {
    source
        .find("\n#[cfg(test)]\nmod tests")
        .map_or(source, |at| &source[..at])
}

/// The names of the functions a Rust source defines (`fn name`, outside comments).
fn rust_functions(source: &str) -> std::collections::BTreeSet<String> {
    let mut out = std::collections::BTreeSet::new();
    for line in source.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(at) = rest.find("fn ") {
            let before = rest[..at].chars().last();
            let after = &rest[at + 3..];
            rest = after;
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                continue;
            }
            let name: String = after
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

/// The functions and entry points each `.wgsl` file adds to the ones before it in its module
/// (a file in both modules once).
fn wgsl_functions_by_file() -> Vec<(&'static str, Vec<String>)> {
    let mut out: Vec<(&'static str, Vec<String>)> = Vec::new();
    for (files, _) in MODULES {
        let mut seen = std::collections::BTreeSet::new();
        for (i, (name, _)) in files.iter().enumerate() {
            let module = parse(&shader::join(files, i + 1), name);
            let all: Vec<String> = module
                .functions
                .iter()
                .filter_map(|(_, f)| f.name.clone())
                .chain(module.entry_points.iter().map(|e| e.name.clone()))
                .collect();
            let added: Vec<String> = all.into_iter().filter(|f| seen.insert(f.clone())).collect();
            if !out.iter().any(|(n, _)| n == name) {
                out.push((*name, added));
            }
        }
    }
    out
}

#[test]
fn every_wgsl_function_has_a_row() {
    let mut missing = Vec::new();
    let mut rows_left: Vec<_> = TWINS.iter().map(|(file, name, _)| (*file, *name)).collect();
    for (file, functions) in wgsl_functions_by_file() {
        for f in functions {
            match rows_left.iter().position(|row| *row == (file, f.as_str())) {
                Some(i) => {
                    rows_left.remove(i);
                }
                None => missing.push(format!("{file}: {f}")),
            }
        }
    }
    assert!(
        missing.is_empty(),
        "WGSL functions without a row in TWINS (give each its Rust twin, or a reason for none): {missing:?}"
    );
    assert!(
        rows_left.is_empty(),
        "rows in TWINS whose WGSL function is gone: {rows_left:?}"
    );
}

#[test]
fn every_rust_twin_exists() {
    let mut gone = Vec::new();
    for (_, wgsl, twin) in TWINS {
        match twin {
            Rust(file, path) => {
                let name = path.rsplit("::").next().unwrap();
                if !rust_functions(rust_source(file)).contains(name) {
                    gone.push(format!("{wgsl} -> core/src/{file}: {path}"));
                }
            }
            NoTwin(reason) => assert!(!reason.is_empty(), "{wgsl}: a reason, please"),
        }
    }
    assert!(gone.is_empty(), "Rust twins that are gone: {gone:?}");
}

#[test]
fn every_step_and_query_function_has_a_twin_or_is_host_only() {
    for file in ["step.rs", "query.rs", "scene.rs", "pairs.rs"] {
        let twins: Vec<&str> = TWINS
            .iter()
            .filter_map(|(_, _, t)| match t {
                Rust(f, path) if *f == file => path.rsplit("::").next(),
                _ => None,
            })
            .collect();
        let host: Vec<&str> = HOST_ONLY
            .iter()
            .filter(|(f, _, _)| *f == file)
            .map(|(_, name, _)| *name)
            .collect();
        let functions = rust_functions(rust_source(file));
        let unlisted: Vec<_> = functions
            .iter()
            .filter(|f| !twins.contains(&f.as_str()) && !host.contains(&f.as_str()))
            .collect();
        assert!(
            unlisted.is_empty(),
            "core/src/{file}: functions with neither a WGSL twin in TWINS nor a HOST_ONLY row: {unlisted:?}"
        );
        let stale: Vec<_> = host.iter().filter(|h| !functions.contains(**h)).collect();
        assert!(
            stale.is_empty(),
            "core/src/{file}: HOST_ONLY rows whose function is gone: {stale:?}"
        );
        let both: Vec<_> = host.iter().filter(|h| twins.contains(h)).collect();
        assert!(
            both.is_empty(),
            "core/src/{file}: both a twin and host-only: {both:?}"
        );
    }
}

/// The field names of a Rust struct in `source`, in order.
fn rust_fields(source: &str, name: &str) -> Vec<String> {
    let start = source
        .find(&format!("struct {name} {{"))
        .unwrap_or_else(|| panic!("no struct {name} in core"));
    let body = &source[start..];
    let body = &body[body.find('{').unwrap() + 1..body.find("\n}").unwrap()];
    body.lines()
        .map(str::trim)
        .filter(|l| !l.starts_with("//") && l.contains(':'))
        .map(|l| {
            l.split(':')
                .next()
                .unwrap()
                .trim()
                .trim_start_matches("pub ")
                .to_string()
        })
        .collect()
}

#[test]
fn march_structs_have_the_rust_fields() {
    let module = whole();
    let layouter = layouter(&module);
    for name in ["MarchState", "NextLeaf", "BoxCrossing"] {
        let (members, _, _) = wgsl_struct(&module, &layouter, name);
        let wgsl: Vec<String> = members.into_iter().map(|(n, _)| n).collect();
        assert_eq!(
            wgsl,
            rust_fields(rust_source("step.rs"), name),
            "{name}: WGSL vs Rust fields"
        );
    }
}
