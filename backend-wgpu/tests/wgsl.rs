//! Keeps the WGSL mirror honest: every file parses and validates with naga, every mirrored
//! struct has its Rust twin's size, alignment-driven member offsets and array stride, and
//! every shared constant has the Rust value.

use std::mem::{offset_of, size_of};

use naga::proc::Layouter;
use naga::valid::{Capabilities, ValidationFlags, Validator};
use naga::{Expression, Literal, Module, TypeInner};
use octoproxy_core::{Particle, StepParams};
use octoproxy_wgpu::shader::{self, SharedValue, FILES};
use octoproxy_wgpu::{ChunkParams, RunParams};

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

#[test]
fn every_wgsl_file_parses_and_validates_after_the_ones_it_needs() {
    for (i, (name, _)) in FILES.iter().enumerate() {
        let module = parse(&shader::source_upto(i + 1), name);
        assert!(
            !module.functions.is_empty() || !module.types.is_empty(),
            "{name} defines nothing"
        );
    }
    let module = whole();
    let entries: Vec<&str> = module
        .entry_points
        .iter()
        .map(|e| e.name.as_str())
        .collect();
    assert_eq!(entries, ["step_kernel", "integrate_kernel"]);
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
    // (WGSL struct, its Rust twin's (member, offset) pairs, the twin's size)
    type Case<'a> = (&'a str, Vec<(String, u32)>, usize);
    let cases: [Case; 3] = [
        (
            "StepParams",
            owned(&[
                ("gravity", offset_of!(StepParams, gravity)),
                ("dt", offset_of!(StepParams, dt)),
                ("restitution", offset_of!(StepParams, restitution)),
                ("friction", offset_of!(StepParams, friction)),
                ("_pad", offset_of!(StepParams, _pad)),
            ]),
            size_of::<StepParams>(),
        ),
        (
            "RunParams",
            owned(&[
                ("use_lut", offset_of!(RunParams, use_lut)),
                ("_pad0", offset_of!(RunParams, _pad0)),
                ("_pad1", offset_of!(RunParams, _pad1)),
                ("_pad2", offset_of!(RunParams, _pad2)),
            ]),
            size_of::<RunParams>(),
        ),
        (
            "ChunkParams",
            owned(&[
                ("count", offset_of!(ChunkParams, count)),
                ("_pad0", offset_of!(ChunkParams, _pad0)),
                ("_pad1", offset_of!(ChunkParams, _pad1)),
                ("_pad2", offset_of!(ChunkParams, _pad2)),
            ]),
            size_of::<ChunkParams>(),
        ),
    ];
    for (name, rust, rust_size) in cases {
        let (members, size, _) = wgsl_struct(&module, &layouter, name);
        assert_eq!(members, rust, "{name} members (name, offset): WGSL vs Rust");
        assert_eq!(size as usize, rust_size, "{name} size");
    }
}

#[test]
fn shared_constants_have_the_rust_values() {
    let module = whole();
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
    for (name, text) in FILES {
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
    ("format.wgsl", "load_header", NoTwin("decodes the header once per invocation; Rust decodes it once per proxy, in ProxyView::new")),
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
    ("step.wgsl", "march", Rust("step.rs", "march")),
    // kernel.wgsl
    ("kernel.wgsl", "particle_index", NoTwin("a particle's index from the dispatch grid; the CPU backend iterates")),
    ("kernel.wgsl", "step_kernel", NoTwin("entry point: one step of one particle; CpuBackend's loop over particles")),
    ("kernel.wgsl", "integrate_kernel", NoTwin("entry point: the bench's floor, integration without collision")),
];

/// The functions of core's step and query modules that run on the host only, and why. With
/// the twins above, every function of `step.rs` and `query.rs` has a row.
const HOST_ONLY: &[(&str, &str, &str)] = &[
    ("step.rs", "fmt", "ParamError's Display: errors are the host's"),
    ("query.rs", "surface_box", "ProxyView::surface_box: the host's scene check (how instances' shells overlap)"),
    ("step.rs", "default", "StepParams::default: the host fills the uniform"),
    ("step.rs", "validate", "StepParams::validate: the host checks parameters before uploading them"),
    ("step.rs", "step_particle", "the unhinted entry point; the GPU always keeps hints (step_particle_hinted with none is the same step)"),
    ("step.rs", "march_from_hint", "keeps the march and settle_on_plane out of line of the hot settles on the CPU; WGSL's step_particle_hinted calls settle_on_plane, then march"),
    ("step.rs", "step_particle_traced", "host-only: ground-truth checks of the path"),
    ("step.rs", "step_hinted_observed", "step_particle_hinted reporting collisions to an observer, for the scene step's hit records; WGSL has no observer yet (the scene step's mirror is not written: docs/scenes.md)"),
    ("step.rs", "march_after", "the scene step's march from the leaf it just collided in (core/src/scene.rs); the scene step has no WGSL mirror yet"),
    ("step.rs", "hit", "MarchObserver::hit: WGSL has no observer"),
    ("step.rs", "step_particle_counted", "host-only: tests count the rare branches"),
    ("step.rs", "add", "MarchCounts, for tests"),
    ("step.rs", "index", "MarchCounts, for tests"),
    ("step.rs", "piece", "the march's observers; WGSL observes nothing"),
    ("step.rs", "branch", "the march's observers; WGSL observes nothing"),
    ("step.rs", "initial_side", "the host seeds particles' sides"),
    ("step.rs", "clamp", "f32::clamp without its assertion; WGSL's is the builtin clamp"),
    ("step.rs", "finish_caged", "finish_march out of line for a step that ends in its cage, to keep the CPU's march small; WGSL calls finish_march"),
    ("query.rs", "key", "LeafInfo::key: the baker's and the tests' leaf identity"),
    ("query.rs", "cell_box", "cell_aabb in SIMD vectors for the settled step; the same floats as WGSL's cell_aabb"),
    ("query.rs", "locate_leaf", "a checked public query; the step uses locate_inside"),
    ("query.rs", "locate_leaf_toward", "a checked public query; the step uses locate_inside"),
    ("query.rs", "locate_leaf_from", "a checked public query; the step uses locate_next"),
];

/// core's source files, by name.
fn rust_source(file: &str) -> &'static str {
    match file {
        "step.rs" => include_str!("../../core/src/step.rs"),
        "query.rs" => include_str!("../../core/src/query.rs"),
        "format.rs" => include_str!("../../core/src/format.rs"),
        "view.rs" => include_str!("../../core/src/view.rs"),
        "particle.rs" => include_str!("../../core/src/particle.rs"),
        other => panic!("no core source {other} in this test"),
    }
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

/// The functions and entry points each `.wgsl` file adds to the ones before it.
fn wgsl_functions_by_file() -> Vec<(&'static str, Vec<String>)> {
    let mut seen = std::collections::BTreeSet::new();
    let mut out = Vec::new();
    for (i, (name, _)) in FILES.iter().enumerate() {
        let module = parse(&shader::source_upto(i + 1), name);
        let all: Vec<String> = module
            .functions
            .iter()
            .filter_map(|(_, f)| f.name.clone())
            .chain(module.entry_points.iter().map(|e| e.name.clone()))
            .collect();
        let added: Vec<String> = all.into_iter().filter(|f| seen.insert(f.clone())).collect();
        out.push((*name, added));
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
    for file in ["step.rs", "query.rs"] {
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
