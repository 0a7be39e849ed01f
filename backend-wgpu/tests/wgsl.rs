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
