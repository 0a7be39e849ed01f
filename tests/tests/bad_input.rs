//! Hostile and bad input, one test each, at the library level: what every bad input gets
//! (the exact error variant, or the documented behaviour for NaN/inf particles).

use octoproxy_core::format::{header, HEADER_WORDS, MAGIC, NODE_WORDS};
use octoproxy_core::{
    step_particle, FormatError, ParamError, Particle, ProxyView, StepOutcome, StepParams,
    FLAG_INVALID, FORMAT_VERSION,
};
use octoproxy_cpu::bake::{bake, BuildError, BuildParams, MeshRef};
use octoproxy_cpu::io::{parse_mesh, MeshError, MeshFormat};
use octoproxy_cpu::io::{parse_particles, ParticleIoError};
use octoproxy_cpu::scenes;

/// A small valid proxy (a cube, dmax 4, with a lookup table).
fn cube_proxy() -> Vec<u32> {
    let cube = scenes::cube([-1.0; 3], [1.0; 3]);
    let params = BuildParams {
        dmin: 2,
        dmax: 4,
        lut_depth: 2,
        ..BuildParams::default()
    };
    bake(&[MeshRef::from(&cube)], &params, &())
        .expect("cube bakes")
        .0
}

fn bad_param(params: BuildParams) -> String {
    let cube = scenes::cube([-1.0; 3], [1.0; 3]);
    match bake(&[MeshRef::from(&cube)], &params, &()) {
        Err(BuildError::BadParam(msg)) => msg,
        other => panic!("{params:?} gave {:?}, not BadParam", other.map(|_| ())),
    }
}

fn bytes_of(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

// ---- proxy files -----------------------------------------------------------------------------

#[test]
fn proxy_truncated_is_truncated() {
    let words = cube_proxy();
    let total = words.len();
    for keep in [
        total - 1,
        total - NODE_WORDS,
        HEADER_WORDS + 1,
        HEADER_WORDS,
    ] {
        assert_eq!(
            ProxyView::new(&words[..keep]).err(),
            Some(FormatError::Truncated {
                needed_words: total,
                have_words: keep
            }),
            "truncated to {keep} of {total} words"
        );
    }
    // Inside the header: the header itself is short.
    assert_eq!(
        ProxyView::new(&words[..5]).err(),
        Some(FormatError::Truncated {
            needed_words: HEADER_WORDS,
            have_words: 5
        })
    );
    assert_eq!(
        ProxyView::new(&[]).err(),
        Some(FormatError::Truncated {
            needed_words: HEADER_WORDS,
            have_words: 0
        })
    );
    // As a file: a byte count that is not whole words.
    let bytes = bytes_of(&words);
    let aligned: Vec<u32> = words.clone();
    let _ = aligned;
    assert_eq!(
        ProxyView::from_bytes(&bytes[..bytes.len() - 3]).err(),
        Some(FormatError::Misaligned {
            len: bytes.len() - 3
        })
    );
}

#[test]
fn proxy_trailing_words_are_rejected() {
    let mut words = cube_proxy();
    let total = words.len();
    words.push(0);
    assert_eq!(
        ProxyView::new(&words).err(),
        Some(FormatError::TrailingWords {
            expected_words: total,
            have_words: total + 1
        })
    );
}

#[test]
fn proxy_bad_magic_is_rejected() {
    let mut words = cube_proxy();
    words[header::MAGIC] ^= 1;
    assert_eq!(
        ProxyView::new(&words).err(),
        Some(FormatError::BadMagic { found: MAGIC ^ 1 })
    );
    // A text file is not a proxy either.
    let text: Vec<u32> = b"solid cube\nfacet normal 0 0 1\n"
        .chunks(4)
        .map(|c| u32::from_le_bytes(std::array::from_fn(|i| c.get(i).copied().unwrap_or(b' '))))
        .collect();
    assert!(matches!(
        ProxyView::new(&text),
        Err(FormatError::BadMagic { .. })
    ));
}

#[test]
fn proxy_version_mismatch_is_unsupported_version() {
    let mut words = cube_proxy();
    for v in [0, 1, FORMAT_VERSION - 1, FORMAT_VERSION + 1, u32::MAX] {
        words[header::VERSION] = v;
        assert_eq!(
            ProxyView::new(&words).err(),
            Some(FormatError::UnsupportedVersion { found: v })
        );
    }
}

#[test]
fn proxy_bit_flips_are_rejected_or_harmless() {
    // Every single-bit flip of a valid proxy is an error: structural damage gets its specific
    // variant, and what structure cannot catch (root box floats, dmin/dmax/epsilon, labels,
    // leaf normals, two-sided bits, plane offsets) the checksum does (format v3; fuzzing
    // found that v2 accepted 1,989 of 2,834 flips of a small proxy silently).
    let words = cube_proxy();
    let mut checksum_caught = 0;
    for i in 0..words.len() {
        for b in 0..32 {
            let mut w = words.clone();
            w[i] ^= 1 << b;
            match ProxyView::new(&w) {
                Ok(_) => panic!("a flip of bit {b} of word {i} was accepted"),
                Err(FormatError::BadChecksum { .. }) => checksum_caught += 1,
                Err(_) => {}
            }
        }
    }
    assert!(
        checksum_caught > 0,
        "the checksum caught nothing the structure missed"
    );
    // The flips that must be caught, with their exact variants.
    let flip = |i: usize, bit: u32| {
        let mut w = words.clone();
        w[i] ^= 1 << bit;
        ProxyView::new(&w).err()
    };
    assert_eq!(
        flip(header::MAGIC, 31),
        Some(FormatError::BadMagic {
            found: MAGIC ^ (1 << 31)
        })
    );
    assert_eq!(
        flip(header::VERSION, 4),
        Some(FormatError::UnsupportedVersion {
            found: FORMAT_VERSION ^ 16
        })
    );
    assert_eq!(
        flip(header::NODE_COUNT, 0),
        Some(FormatError::BadHeader {
            word: header::LUT_OFFSET,
            value: words[header::LUT_OFFSET]
        })
    );
    assert_eq!(
        flip(header::TOTAL_WORDS, 0),
        Some(FormatError::BadHeader {
            word: header::TOTAL_WORDS,
            value: words[header::TOTAL_WORDS] ^ 1
        })
    );
    // The root box's size with its sign bit set.
    assert_eq!(flip(header::ROOT_SIZE, 31), Some(FormatError::BadRootBox));
    // The root record's leaf bit.
    assert_eq!(flip(HEADER_WORDS, 31), Some(FormatError::RootIsLeaf));
    // The last word (a lookup-table entry).
    let last = words.len() - 1;
    assert_eq!(
        flip(last, 0),
        Some(FormatError::BadLookupEntry {
            entry: words[header::TOTAL_WORDS] - words[header::LUT_OFFSET] - 1,
            value: words[last] ^ 1
        })
    );
}

#[test]
fn proxy_header_out_of_range_is_bad_header() {
    let words = cube_proxy();
    let set = |i: usize, v: u32| {
        let mut w = words.clone();
        w[i] = v;
        ProxyView::new(&w).err()
    };
    assert_eq!(
        set(header::TREE_DEPTH, 0),
        Some(FormatError::BadHeader {
            word: header::TREE_DEPTH,
            value: 0
        })
    );
    assert_eq!(
        set(header::TREE_DEPTH, 40),
        Some(FormatError::BadHeader {
            word: header::TREE_DEPTH,
            value: 40
        })
    );
    assert_eq!(
        set(header::DMAX, 40),
        Some(FormatError::BadHeader {
            word: header::DMAX,
            value: 40
        })
    );
    assert_eq!(
        set(header::NODE_COUNT, 0),
        Some(FormatError::BadHeader {
            word: header::NODE_COUNT,
            value: 0
        })
    );
    assert_eq!(
        set(header::LUT_DEPTH, 9),
        Some(FormatError::BadHeader {
            word: header::LUT_DEPTH,
            value: 9
        })
    );
    assert_eq!(
        set(header::EPSILON, f32::NAN.to_bits()),
        Some(FormatError::BadHeader {
            word: header::EPSILON,
            value: f32::NAN.to_bits()
        })
    );
    assert_eq!(
        set(header::ROOT_MIN, f32::INFINITY.to_bits()),
        Some(FormatError::BadRootBox)
    );
    // A node count that would need a huge buffer: rejected by arithmetic, not by allocating.
    assert!(matches!(
        set(header::NODE_COUNT, u32::MAX),
        Some(FormatError::BadHeader {
            word: header::NODE_COUNT,
            ..
        })
    ));
}

// ---- build parameters ------------------------------------------------------------------------

#[test]
fn build_dmax_out_of_range_is_bad_param() {
    assert_eq!(
        bad_param(BuildParams {
            dmax: 0,
            dmin: 0,
            ..BuildParams::default()
        }),
        "dmax must be in 2..=16, got 0"
    );
    assert_eq!(
        bad_param(BuildParams {
            dmax: 40,
            ..BuildParams::default()
        }),
        "dmax must be in 2..=16, got 40"
    );
    assert_eq!(
        bad_param(BuildParams {
            dmax: 1,
            dmin: 0,
            ..BuildParams::default()
        }),
        "dmax must be in 2..=16, got 1"
    );
    assert_eq!(
        bad_param(BuildParams {
            dmax: 17,
            ..BuildParams::default()
        }),
        "dmax must be in 2..=16, got 17"
    );
}

#[test]
fn build_dmin_above_dmax_is_bad_param() {
    assert_eq!(
        bad_param(BuildParams {
            dmin: 9,
            dmax: 8,
            ..BuildParams::default()
        }),
        "dmin (9) must not exceed dmax (8)"
    );
}

#[test]
fn build_bad_epsilon_is_bad_param() {
    assert_eq!(
        bad_param(BuildParams {
            epsilon: -0.1,
            ..BuildParams::default()
        }),
        "epsilon must be a finite number >= 0, got -0.1"
    );
    assert_eq!(
        bad_param(BuildParams {
            epsilon: f32::NAN,
            ..BuildParams::default()
        }),
        "epsilon must be a finite number >= 0, got NaN"
    );
    assert_eq!(
        bad_param(BuildParams {
            epsilon: f32::INFINITY,
            ..BuildParams::default()
        }),
        "epsilon must be a finite number >= 0, got inf"
    );
}

#[test]
fn build_lut_depth_too_big_is_bad_param() {
    assert_eq!(
        bad_param(BuildParams {
            lut_depth: 9,
            ..BuildParams::default()
        }),
        "lut-depth must be in 0..=8, got 9"
    );
}

#[test]
fn build_too_many_nodes_is_too_many_nodes() {
    let sphere = scenes::uv_sphere([0.0; 3], 1.0, 16, 8);
    let params = BuildParams {
        dmin: 8,
        dmax: 8,
        max_nodes: 1000,
        ..BuildParams::default()
    };
    assert!(matches!(
        bake(&[MeshRef::from(&sphere)], &params, &()),
        Err(BuildError::TooManyNodes { max_nodes: 1000 })
    ));
}

// ---- step parameters -------------------------------------------------------------------------

#[test]
fn step_dt_nan_zero_negative_infinite_is_bad_dt() {
    let with = |dt: f32| {
        StepParams {
            dt,
            ..StepParams::default()
        }
        .validate()
    };
    assert!(matches!(with(f32::NAN), Err(ParamError::BadDt(d)) if d.is_nan()));
    assert_eq!(with(0.0), Err(ParamError::BadDt(0.0)));
    assert_eq!(with(-1.0 / 60.0), Err(ParamError::BadDt(-1.0 / 60.0)));
    assert_eq!(with(f32::INFINITY), Err(ParamError::BadDt(f32::INFINITY)));
    assert_eq!(
        with(f32::NEG_INFINITY),
        Err(ParamError::BadDt(f32::NEG_INFINITY))
    );
    assert_eq!(
        with(f32::NAN).unwrap_err().to_string(),
        "dt must be a positive finite number of seconds, got NaN"
    );
}

#[test]
fn step_dt_huge_is_accepted_and_overflow_flags_invalid() {
    // A huge but finite dt is valid; a particle whose step overflows f32 is flagged invalid
    // and left unchanged (the documented behaviour for non-finite state), never NaN.
    let params = StepParams {
        dt: 1e30,
        ..StepParams::default()
    };
    assert_eq!(params.validate(), Ok(()));
    let words = cube_proxy();
    let view = ProxyView::new(&words).expect("valid");
    let start = Particle::new([0.0, 5.0, 0.0], [0.0, 0.0, 0.0]);
    let mut p = start;
    assert_eq!(step_particle(&view, &mut p, &params), StepOutcome::Invalid);
    assert_ne!(p.flags & FLAG_INVALID, 0);
    assert_eq!((p.position, p.velocity), (start.position, start.velocity));
    // Without gravity the same dt moves a slow particle a finite distance: a normal step.
    let calm = StepParams {
        gravity: [0.0; 3],
        ..params
    };
    let mut q = Particle::new([0.0, 5.0, 0.0], [1e-20, 0.0, 0.0]);
    assert_eq!(step_particle(&view, &mut q, &calm), StepOutcome::Done);
    assert!(q.position.iter().all(|c| c.is_finite()));
}

#[test]
fn step_bad_gravity_restitution_friction_are_rejected() {
    let d = StepParams::default();
    assert_eq!(
        StepParams {
            gravity: [0.0, f32::NAN, 0.0],
            ..d
        }
        .validate(),
        Err(ParamError::BadGravity)
    );
    assert_eq!(
        StepParams {
            gravity: [f32::INFINITY, 0.0, 0.0],
            ..d
        }
        .validate(),
        Err(ParamError::BadGravity)
    );
    assert_eq!(
        StepParams {
            restitution: 1.5,
            ..d
        }
        .validate(),
        Err(ParamError::BadRestitution(1.5))
    );
    assert_eq!(
        StepParams {
            restitution: -0.1,
            ..d
        }
        .validate(),
        Err(ParamError::BadRestitution(-0.1))
    );
    assert!(
        matches!(StepParams { restitution: f32::NAN, ..d }.validate(), Err(ParamError::BadRestitution(r)) if r.is_nan())
    );
    assert_eq!(
        StepParams {
            friction: -1.0,
            ..d
        }
        .validate(),
        Err(ParamError::BadFriction(-1.0))
    );
    assert_eq!(
        StepParams {
            friction: f32::INFINITY,
            ..d
        }
        .validate(),
        Err(ParamError::BadFriction(f32::INFINITY))
    );
}

// ---- meshes ----------------------------------------------------------------------------------

#[test]
fn mesh_nan_coordinates_are_non_finite() {
    let obj = b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n";
    assert!(matches!(
        parse_mesh("m.obj", obj, None),
        Err(MeshError::NonFinite {
            vertex: 1,
            line: Some(2),
            ..
        })
    ));
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 inf 0\n3 0 1 2\n";
    assert!(matches!(
        parse_mesh("m.ply", ply, None),
        Err(MeshError::NonFinite { vertex: 2, .. })
    ));
    let stl = b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 NaN 0\nendloop\nendfacet\nendsolid t\n";
    assert!(matches!(
        parse_mesh("m.stl", stl, None),
        Err(MeshError::NonFinite { .. })
    ));
    // In memory, straight to the baker.
    let positions = [[0.0, 0.0, 0.0], [1.0, f32::NAN, 0.0], [0.0, 1.0, 0.0]];
    let e = bake(
        &[MeshRef {
            positions: &positions,
            triangles: &[[0, 1, 2]],
        }],
        &BuildParams::default(),
        &(),
    )
    .err();
    assert!(
        matches!(e, Some(BuildError::NonFinite { mesh: 0, vertex: 1 })),
        "{e:?}"
    );
}

#[test]
fn mesh_empty_is_empty() {
    for (name, bytes) in [
        ("e.obj", &b""[..]),
        ("e.obj", b"# nothing\nv 0 0 0\n"),
        ("e.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"),
        ("e.stl", b"solid e\nendsolid e\n"),
    ] {
        let e = parse_mesh(name, bytes, None).err();
        assert!(matches!(e, Some(MeshError::Empty { .. })), "{name}: {e:?}");
        assert!(e.expect("error").to_string().contains("the mesh is empty"));
    }
    // No meshes, or meshes with no triangles, in the baker.
    assert!(matches!(
        bake(&[], &BuildParams::default(), &()),
        Err(BuildError::Empty { degenerate: 0 })
    ));
    let e = bake(
        &[MeshRef {
            positions: &[[0.0; 3]],
            triangles: &[],
        }],
        &BuildParams::default(),
        &(),
    )
    .err();
    assert!(
        matches!(e, Some(BuildError::Empty { degenerate: 0 })),
        "{e:?}"
    );
}

#[test]
fn mesh_only_degenerate_triangles_is_empty() {
    // Every triangle in one point, or on one line.
    let positions = [
        [1.0, 2.0, 3.0],
        [1.0, 2.0, 3.0],
        [1.0, 2.0, 3.0],
        [2.0, 2.0, 3.0],
        [3.0, 2.0, 3.0],
    ];
    let e = bake(
        &[MeshRef {
            positions: &positions,
            triangles: &[[0, 1, 2], [0, 3, 4], [2, 2, 2]],
        }],
        &BuildParams::default(),
        &(),
    )
    .err();
    assert!(
        matches!(e, Some(BuildError::Empty { degenerate: 3 })),
        "{e:?}"
    );
}

#[test]
fn mesh_single_triangle_bakes_and_collides() {
    let obj = b"v -1 0 -1\nv 1 0 -1\nv 0 0 1\nf 1 3 2\n";
    let (mesh, _) = parse_mesh("t.obj", obj, None).expect("a single triangle reads");
    assert_eq!(mesh.triangles.len(), 1);
    let (words, report) = bake(&[MeshRef::from(&mesh)], &BuildParams::default(), &())
        .expect("a single triangle bakes");
    assert_eq!(report.closed_triangles, 0);
    let view = ProxyView::new(&words).expect("valid");
    let mut p = Particle::new([0.0, 0.5, -0.2], [0.0, 0.0, 0.0]);
    for _ in 0..120 {
        step_particle(&view, &mut p, &StepParams::default());
    }
    assert!(
        p.position[1] >= -0.05,
        "fell through a single triangle: {p:?}"
    );
    assert!(p.collisions() > 0);
}

#[test]
fn mesh_non_manifold_bakes_as_open() {
    // Three triangles on one edge (a "book" of three pages), plus a duplicated triangle.
    let positions = [
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.5],
        [-1.0, 0.0, -0.5],
    ];
    let triangles = [[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 1, 2]];
    let (words, report) = bake(
        &[MeshRef {
            positions: &positions,
            triangles: &triangles,
        }],
        &BuildParams::default(),
        &(),
    )
    .expect("non-manifold geometry bakes");
    assert_eq!(
        report.closed_triangles, 0,
        "a non-manifold component is open"
    );
    assert!(report.two_sided_leaves > 0, "its rim leaves are solid");
    ProxyView::new(&words).expect("valid");
}

#[test]
fn mesh_indices_out_of_range_are_index_out_of_range() {
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n";
    assert!(matches!(
        parse_mesh("m.obj", obj, None),
        Err(MeshError::IndexOutOfRange {
            index: 4,
            vertices: 3,
            face: 0,
            line: Some(4),
            ..
        })
    ));
    let obj0 = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n";
    assert!(matches!(
        parse_mesh("m.obj", obj0, None),
        Err(MeshError::IndexOutOfRange { index: 0, .. })
    ));
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
    assert!(matches!(
        parse_mesh("m.ply", ply, None),
        Err(MeshError::IndexOutOfRange {
            index: 3,
            vertices: 3,
            ..
        })
    ));
    let plyneg = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n";
    assert!(matches!(
        parse_mesh("m.ply", plyneg, None),
        Err(MeshError::IndexOutOfRange { index: -1, .. })
    ));
    let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let e = bake(
        &[MeshRef {
            positions: &positions,
            triangles: &[[0, 1, 2], [0, 1, 7]],
        }],
        &BuildParams::default(),
        &(),
    )
    .err();
    assert!(
        matches!(
            e,
            Some(BuildError::IndexOutOfRange {
                mesh: 0,
                triangle: 1,
                index: 7,
                vertices: 3
            })
        ),
        "{e:?}"
    );
}

#[test]
fn mesh_garbage_and_corrupt_gzip_are_errors() {
    assert!(matches!(
        parse_mesh("x.bin", b"\x00\x01\x02garbage", None),
        Err(MeshError::UnknownFormat { .. })
    ));
    let e = parse_mesh("x.obj.gz", b"\x1f\x8b\x08\x00garbage-not-deflate", None).err();
    assert!(matches!(e, Some(MeshError::Decompress { .. })), "{e:?}");
    // A binary STL that claims more triangles than it holds.
    let mut stl = vec![0u8; 80];
    stl.extend(1000u32.to_le_bytes());
    stl.extend([0u8; 50]);
    let e = parse_mesh("x.stl", &stl, Some(MeshFormat::Stl)).err();
    assert!(matches!(e, Some(MeshError::Parse { .. })), "{e:?}");
}

// ---- particles -------------------------------------------------------------------------------

fn particle_ply(props: &[&str], rows: &str) -> Vec<u8> {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\n",
        rows.lines().count()
    );
    for p in props {
        s.push_str(&format!("property float {p}\n"));
    }
    s.push_str("end_header\n");
    s.push_str(rows);
    s.into_bytes()
}

#[test]
fn particles_missing_x_y_or_z_is_missing_property() {
    for (props, missing) in [(["y", "z"], "x"), (["x", "z"], "y"), (["x", "y"], "z")] {
        let e = parse_particles("p.ply", &particle_ply(&props, "1 2\n")).err();
        match e {
            Some(ParticleIoError::MissingProperty { ref property, .. }) => {
                assert_eq!(property, missing)
            }
            other => panic!("missing {missing}: {other:?}"),
        }
        let msg = e.expect("error").to_string();
        assert!(msg.contains(&format!("no `{missing}` property")), "{msg}");
    }
}

#[test]
fn particles_partial_velocity_is_parse_error() {
    let e = parse_particles("p.ply", &particle_ply(&["x", "y", "z", "vx"], "1 2 3 4\n")).err();
    assert!(
        matches!(&e, Some(ParticleIoError::Parse { message, .. }) if message.contains("vx, vy, vz")),
        "{e:?}"
    );
}

#[test]
fn particles_nan_and_inf_are_flagged_invalid_and_unchanged() {
    let cloud = parse_particles(
        "p.ply",
        &particle_ply(
            &["x", "y", "z", "vx", "vy", "vz"],
            "nan 0 0 0 0 0\n0 inf 0 0 0 0\n0 0 0 0 -inf 0\n0 0.5 0 0 0 0\n",
        ),
    )
    .expect("NaN and inf are readable values");
    assert_eq!(cloud.particles.len(), 4);
    let words = cube_proxy();
    let view = ProxyView::new(&words).expect("valid");
    for (i, start) in cloud.particles.iter().enumerate() {
        let mut p = *start;
        let outcome = step_particle(&view, &mut p, &StepParams::default());
        if i < 3 {
            assert_eq!(outcome, StepOutcome::Invalid, "particle {i}");
            assert_ne!(p.flags & FLAG_INVALID, 0, "particle {i} not flagged");
            let same = |a: [f32; 3], b: [f32; 3]| {
                a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits())
            };
            assert!(
                same(p.position, start.position) && same(p.velocity, start.velocity),
                "particle {i} changed"
            );
            // And it stays so: stepping again changes nothing.
            let again = p;
            step_particle(&view, &mut p, &StepParams::default());
            assert!(same(p.position, again.position) && p.flags & FLAG_INVALID != 0);
        } else {
            assert_eq!(outcome, StepOutcome::Done);
            assert_eq!(p.flags & FLAG_INVALID, 0);
        }
    }
}

#[test]
fn particles_truncated_binary_is_parse_error() {
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    bytes.extend([0u8; 24]);
    let e = parse_particles("p.ply", &bytes).err();
    assert!(matches!(e, Some(ParticleIoError::Parse { .. })), "{e:?}");
}

// ---- scenes (glTF, baked scenes, poses) ------------------------------------------------------

/// The Khronos `Box` sample (a matrix node over a node with a mesh), as text to break.
fn box_gltf() -> String {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../backend-cpu/tests/data/gltf/khronos/Box.gltf"
    );
    std::fs::read_to_string(path).expect("the Box sample")
}

/// `text` with `from` replaced (once, and it must be there) by `to`.
fn broken(text: &str, from: &str, to: &str) -> Vec<u8> {
    assert!(text.contains(from), "{from:?} is not in the sample");
    text.replacen(from, to, 1).into_bytes()
}

#[test]
fn bad_gltf_is_an_error_naming_the_file_and_what_is_wrong() {
    use octoproxy_cpu::gltf::parse_gltf;
    let text = box_gltf();
    assert!(parse_gltf("box.gltf", text.as_bytes(), None).is_ok());
    let cases: [(&str, Vec<u8>, &str); 7] = [
        (
            "truncated",
            text.as_bytes()[..text.len() / 2].to_vec(),
            "box.gltf",
        ),
        ("not JSON", b"glTF? no".to_vec(), "box.gltf"),
        // 36 indices read from a 72-byte view: 360 do not fit.
        (
            "accessor past its view",
            broken(&text, "\"count\": 36", "\"count\": 360"),
            "mesh 0",
        ),
        // Positions from the indices' accessor: unsigned short scalars, not float triples.
        (
            "wrong accessor type",
            broken(&text, "\"POSITION\": 2", "\"POSITION\": 0"),
            "mesh 0",
        ),
        // An index past the 24 vertices (the max says 23; the data is what counts: a bad
        // buffer view points the indices at the positions' floats).
        (
            "index out of range",
            broken(&text, "\"byteOffset\": 576", "\"byteOffset\": 0"),
            "mesh 0",
        ),
        (
            "a skin",
            broken(&text, "\"mesh\": 0,", "\"mesh\": 0, \"skin\": 0,"),
            "deforming meshes",
        ),
        (
            "non-uniform scale",
            broken(
                &text,
                "\"mesh\": 0,\n            \"matrix\": [\n                1.0,",
                "\"mesh\": 0,\n            \"matrix\": [\n                3.0,",
            ),
            "node 1",
        ),
    ];
    for (what, bytes, needle) in cases {
        let e = parse_gltf("box.gltf", &bytes, None).err();
        let msg = e.map(|e| e.to_string()).unwrap_or_default();
        assert!(msg.starts_with("box.gltf"), "{what}: {msg:?}");
        assert!(
            msg.contains(needle),
            "{what}: {msg:?} should say {needle:?}"
        );
    }
}

#[test]
fn a_damaged_baked_scene_is_an_error_naming_the_file() {
    use octoproxy_cpu::gltf::{bake_scene, parse_gltf, BakedScene};
    let (scene, _) = parse_gltf("box.gltf", box_gltf().as_bytes(), None).expect("reads");
    let params = BuildParams {
        dmax: 3,
        dmin: 2,
        lut_depth: 0,
        ..BuildParams::default()
    };
    let (baked, _) = bake_scene(&scene, &params, &()).expect("bakes");
    let bytes = baked.encode();
    assert!(BakedScene::parse("s.octoscene", &bytes).is_ok());
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x10;
    let mut version = bytes.clone();
    version[8] ^= 2;
    for (what, b) in [
        ("truncated", &bytes[..bytes.len() - 3]),
        ("a bit flipped", &flipped[..]),
        ("another version", &version[..]),
        ("empty", &[][..]),
    ] {
        let msg = BakedScene::parse("s.octoscene", b)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(msg.starts_with("s.octoscene"), "{what}: {msg:?}");
    }
}

#[test]
fn bad_poses_are_refused_naming_the_instance() {
    use octoproxy_core::{Pose, SceneError};
    use octoproxy_cpu::{Scene, SceneBuildError};
    let cube = octoproxy_cpu::scenes::cube([-0.5; 3], [0.5; 3]);
    let (words, _) = bake(
        &[MeshRef::from(&cube)],
        &BuildParams {
            dmax: 5,
            ..BuildParams::default()
        },
        &(),
    )
    .expect("bakes");
    let mut scene = Scene::new();
    let proxy = scene.add_proxy(words).expect("valid");
    let i = scene.add_instance(proxy, Pose::IDENTITY).expect("valid");
    for bad in [
        Pose {
            translation: [f32::NAN, 0.0, 0.0],
            ..Pose::IDENTITY
        },
        Pose {
            rotation: [0.0, 0.0, 0.0, 2.0],
            ..Pose::IDENTITY
        },
        Pose {
            scale: -1.0,
            ..Pose::IDENTITY
        },
    ] {
        let e = scene.move_to(i, bad).err();
        assert!(
            matches!(e, Some(SceneBuildError::BadPose { instance, .. }) if instance == i),
            "{bad:?}: {e:?}"
        );
    }
    // So far out that f32 cannot resolve a leaf of the proxy there.
    scene
        .move_to(
            i,
            Pose {
                translation: [3e7, 0.0, 0.0],
                ..Pose::IDENTITY
            },
        )
        .expect("a finite pose");
    let e = scene.prepare().err();
    assert!(
        matches!(e, Some(SceneBuildError::Scene(SceneError::TooFarOut { instance })) if instance == i),
        "{e:?}"
    );
    assert!(e
        .expect("an error")
        .to_string()
        .contains(&format!("instance {i}")));
}
