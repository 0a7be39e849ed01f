//! The mesh readers' tests: OBJ, STL, PLY meshes, gzip, format detection, hostile input.

use super::*;
use crate::io::ply::{Element, Encoding, Property, PropertyKind, Scalar, Writer};
use std::io::Write as _;

fn parse(name: &str, bytes: &[u8]) -> Result<(Mesh, LoadReport), MeshError> {
    parse_mesh(name, bytes, None)
}

fn gz(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

const CUBE_OBJ: &str = "# a cube\r\nmtllib cube.mtl\r\no cube\r\n\
    v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0 1.0\r\n\
    v 0 0 1 0.5 0.5 0.5\r\nv 1 0 1\r\nv 1 1 1\r\nv 0 1 1\r\n\
    vt 0 0\r\nvn 0 0 1\r\ng side\r\ns off\r\nusemtl red\r\n\
    f 1 4 3 2\r\n\
    f 5/1 6/1 7/1 8/1\r\n\
    f 1//1 2//1 6//1 5//1\r\n\
    f 2/1/1 3/1/1 7/1/1 6/1/1 # comment after\r\n\
    f -5 -1 -2 -6\r\n\
    f 4 1 5\r\nf 4 5 8\r\nl 1 2\r\n\r\n";

#[test]
fn obj_all_face_forms_quads_and_negative_indices() {
    let (m, r) = parse("cube.obj", CUBE_OBJ.as_bytes()).unwrap();
    assert_eq!(m.positions.len(), 8);
    assert_eq!(m.positions[3], [0.0, 1.0, 0.0]);
    assert_eq!(m.positions[4], [0.0, 0.0, 1.0]);
    assert_eq!(
        r,
        LoadReport {
            polygons_triangulated: 5,
            gzipped: false
        }
    );
    assert_eq!(m.triangles.len(), 12);
    assert_eq!(m.triangles[0], [0, 3, 2]);
    assert_eq!(m.triangles[1], [0, 2, 1]);
    assert_eq!(m.triangles[2], [4, 5, 6]);
    // f -5 -1 -2 -6 with 8 vertices: 4 8 7 3 (1-based).
    assert_eq!(m.triangles[8], [3, 7, 6]);
    assert_eq!(m.triangles[9], [3, 6, 2]);
    assert_eq!(m.triangles[11], [3, 4, 7]);
}

#[test]
fn obj_lines_continue_after_a_backslash() {
    let obj = b"v 0 0 \\\n 0\nv 1 0 0\r\nv 1 1 0\nv 0 1 0\nf 1 2 \\ \r\n 3 \\\n4\n";
    let (m, r) = parse("c.obj", obj).unwrap();
    assert_eq!(
        m.positions,
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0]
        ]
    );
    assert_eq!(r.polygons_triangulated, 1);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    // A face cut short by the end of the file: its error names the line it began on.
    let bad = [&obj[..], b"f 1 2 \\"].concat();
    let e = parse("c.obj", &bad).unwrap_err().to_string();
    assert!(
        e.contains("line 9") && e.contains("at least 3 vertices"),
        "{e}"
    );
}

#[test]
fn obj_forward_references_are_allowed() {
    let (m, _) = parse("f.obj", b"f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
}

#[test]
fn obj_errors() {
    let e = parse("bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 7\n").unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::IndexOutOfRange {
                face: 1,
                index: 7,
                vertices: 3,
                line: Some(5),
                ..
            }
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(
        msg.starts_with("bad.obj, line 5: face 1")
            && msg.contains("vertex 7")
            && msg.contains("3 vertices"),
        "{msg}"
    );
    let e = parse("neg.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n").unwrap_err();
    assert!(
        matches!(e, MeshError::IndexOutOfRange { index: -4, .. }),
        "{e:?}"
    );
    let e = parse("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n").unwrap_err();
    assert!(
        matches!(e, MeshError::IndexOutOfRange { index: 0, .. }),
        "{e:?}"
    );
    let e = parse("nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n").unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::NonFinite {
                vertex: 1,
                line: Some(2),
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("nan.obj, line 2: vertex 1"), "{e}");
    let e = parse("inf.obj", b"v 0 0 1e39\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap_err();
    assert!(matches!(e, MeshError::NonFinite { vertex: 0, .. }), "{e:?}");
    let e = parse("two.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("two.obj, line 3") && e.contains("at least 3 vertices"),
        "{e}"
    );
    let e = parse("short.obj", b"v 0 0\n").unwrap_err().to_string();
    assert!(
        e.contains("short.obj, line 1") && e.contains("three coordinates"),
        "{e}"
    );
    let e = parse("word.obj", b"v 0 0 zero\n").unwrap_err().to_string();
    assert!(e.contains("`zero` is not a number"), "{e}");
    let e = parse("ref.obj", b"v 0 0 0\nf 1 x/2 3\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("`x/2` is not a vertex reference"), "{e}");
    let e = parse("points.obj", b"v 0 0 0\nv 1 0 0\n").unwrap_err();
    assert!(matches!(e, MeshError::Empty { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "points.obj: the mesh is empty (no triangles)"
    );
    let e = parse(
        "huge.obj",
        b"v 0 0 0\nv 1 0 0\nv 1 1 1\nf 1 2 99999999999999999\n",
    )
    .unwrap_err();
    assert!(matches!(e, MeshError::IndexOutOfRange { .. }), "{e:?}");
}

/// A binary STL of `tris`, with `header` at the start of the 80-byte header.
fn binary_stl(header: &[u8], tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b[..header.len()].copy_from_slice(header);
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0; 12]);
        for v in t {
            for c in v {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0; 2]);
    }
    b
}

const TWO_TRIS: [[[f32; 3]; 3]; 2] = [
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
    [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
];

#[test]
fn stl_binary_welds_vertices() {
    for header in [&b"binary"[..], b"solid but binary"] {
        let (m, r) = parse("two.stl", &binary_stl(header, &TWO_TRIS)).unwrap();
        assert_eq!(
            m.positions,
            vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0]
            ]
        );
        assert_eq!(m.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        assert_eq!(r, LoadReport::default());
        // Detected from content as well.
        let (m2, _) = parse("noname", &binary_stl(header, &TWO_TRIS)).unwrap();
        assert_eq!(m2, m);
    }
}

#[test]
fn stl_ascii() {
    let text = "solid two triangles\n  facet normal 0 0 1\n    outer loop\n      vertex 0 0 0\n      vertex 1 0 0\n      vertex 0 1 0\n    endloop\n  endfacet\n\
        facet normal 0 0 1\r\nouter loop\r\nvertex 1 0 0\r\nvertex 1 1 0\r\nvertex 0 1 0\r\nendloop\r\nendfacet\r\nendsolid two triangles\n";
    let (m, _) = parse("two.stl", text.as_bytes()).unwrap();
    assert_eq!(m.positions.len(), 4);
    assert_eq!(m.triangles, vec![[0, 1, 2], [1, 3, 2]]);
    let (m2, _) = parse("no extension", text.as_bytes()).unwrap();
    assert_eq!(m2, m);
}

#[test]
fn stl_errors() {
    let mut truncated = binary_stl(b"x", &TWO_TRIS);
    truncated.truncate(truncated.len() - 7);
    let e = parse("cut.stl", &truncated).unwrap_err().to_string();
    assert!(
        e.starts_with("cut.stl: not an STL file")
            && e.contains("2 triangles")
            && e.contains("184 bytes"),
        "{e}"
    );
    let mut solid_cut = binary_stl(b"solid", &TWO_TRIS);
    solid_cut.truncate(150);
    let e = parse("cut2.stl", &solid_cut).unwrap_err().to_string();
    assert!(
        e.contains("cut2.stl") && e.contains("need 184 bytes, but the file has 150"),
        "{e}"
    );
    let e = parse("tiny.stl", b"abc").unwrap_err().to_string();
    assert!(e.contains("too short"), "{e}");
    let nan = binary_stl(
        b"",
        &[[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]]],
    );
    let e = parse("nan.stl", &nan).unwrap_err();
    assert!(matches!(e, MeshError::NonFinite { vertex: 1, .. }), "{e:?}");
    let e = parse("empty.stl", &binary_stl(b"", &[])).unwrap_err();
    assert!(matches!(e, MeshError::Empty { .. }), "{e:?}");
    let e = parse(
        "open.stl",
        b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("open.stl, line 4") && e.contains("ends inside"),
        "{e}"
    );
    let e = parse(
        "two.stl",
        b"solid x\nouter loop\nvertex 0 0 0\nvertex 1 1 1\nendloop\nendsolid\n",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("line 5") && e.contains("at least 3 vertices"),
        "{e}"
    );
    let e = parse(
        "inf.stl",
        b"solid x\nouter loop\nvertex 0 0 0\nvertex 1 1 inf\n",
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::NonFinite {
                line: Some(4),
                vertex: 1,
                ..
            }
        ),
        "{e:?}"
    );
}

fn ply_mesh(encoding: Encoding, positions: &[[f64; 3]], faces: &[Vec<f64>]) -> Vec<u8> {
    let scalar = |n: &str, s| Property {
        name: n.into(),
        kind: PropertyKind::Scalar(s),
    };
    let elements = [
        Element {
            name: "material".into(),
            count: 1,
            properties: vec![scalar("shine", Scalar::F64)],
        },
        Element {
            name: "vertex".into(),
            count: positions.len(),
            properties: vec![
                scalar("red", Scalar::U8),
                scalar("z", Scalar::F64),
                Property {
                    name: "junk".into(),
                    kind: PropertyKind::List {
                        count: Scalar::U8,
                        item: Scalar::I16,
                    },
                },
                scalar("y", Scalar::F32),
                scalar("x", Scalar::F32),
            ],
        },
        Element {
            name: "face".into(),
            count: faces.len(),
            properties: vec![
                scalar("flags", Scalar::I32),
                Property {
                    name: "vertex_index".into(),
                    kind: PropertyKind::List {
                        count: Scalar::U16,
                        item: Scalar::U32,
                    },
                },
                scalar("quality", Scalar::F32),
            ],
        },
        Element {
            name: "edge".into(),
            count: 1,
            properties: vec![scalar("a", Scalar::I32), scalar("b", Scalar::I32)],
        },
    ];
    let mut w = Writer::new(encoding, &elements, &["test"]);
    w.scalar(Scalar::F64, 0.5);
    w.end_entry();
    for p in positions {
        w.scalar(Scalar::U8, 200.0);
        w.scalar(Scalar::F64, p[2]);
        w.list(Scalar::U8, Scalar::I16, &[-1.0, 2.0]);
        w.scalar(Scalar::F32, p[1]);
        w.scalar(Scalar::F32, p[0]);
        w.end_entry();
    }
    for f in faces {
        w.scalar(Scalar::I32, -3.0);
        w.list(Scalar::U16, Scalar::U32, f);
        w.scalar(Scalar::F32, 1.0);
        w.end_entry();
    }
    w.scalar(Scalar::I32, 0.0);
    w.scalar(Scalar::I32, 1.0);
    w.end_entry();
    w.finish()
}

const SQUARE: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.25],
    [1.0, 1.0, 0.5],
    [0.0, 1.0, 0.75],
];

#[test]
fn ply_all_encodings_with_other_elements_and_properties() {
    for enc in [
        Encoding::Ascii,
        Encoding::BinaryLittleEndian,
        Encoding::BinaryBigEndian,
    ] {
        let bytes = ply_mesh(
            enc,
            &SQUARE,
            &[vec![0.0, 1.0, 2.0, 3.0], vec![0.0, 2.0, 1.0]],
        );
        let (m, r) = parse("square.ply", &bytes).unwrap();
        assert_eq!(
            m.positions,
            SQUARE
                .iter()
                .map(|p| p.map(|c| c as f32))
                .collect::<Vec<_>>(),
            "{enc:?}"
        );
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 2, 1]]);
        assert_eq!(r.polygons_triangulated, 1);
        let (m2, _) = parse_mesh("whatever.bin", &bytes, Some(MeshFormat::Ply)).unwrap();
        assert_eq!(m2, m);
        assert_eq!(detect_format("noext", &bytes), Some(MeshFormat::Ply));
    }
}

#[test]
fn ply_errors() {
    for enc in [Encoding::Ascii, Encoding::BinaryLittleEndian] {
        let e = parse("oob.ply", &ply_mesh(enc, &SQUARE, &[vec![0.0, 1.0, 4.0]])).unwrap_err();
        assert!(
            matches!(
                e,
                MeshError::IndexOutOfRange {
                    face: 0,
                    index: 4,
                    vertices: 4,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("oob.ply"), "{e}");
        let mut nan = SQUARE;
        nan[2][1] = f64::NAN;
        let e = parse("nan.ply", &ply_mesh(enc, &nan, &[vec![0.0, 1.0, 2.0]])).unwrap_err();
        assert!(matches!(e, MeshError::NonFinite { vertex: 2, .. }), "{e:?}");
        let mut big = SQUARE;
        big[1][2] = 1e300; // finite double, infinite as f32
        let e = parse("big.ply", &ply_mesh(enc, &big, &[vec![0.0, 1.0, 2.0]])).unwrap_err();
        assert!(matches!(e, MeshError::NonFinite { vertex: 1, .. }), "{e:?}");
        let e = parse("empty.ply", &ply_mesh(enc, &SQUARE, &[])).unwrap_err();
        assert!(matches!(e, MeshError::Empty { .. }), "{e:?}");
        let e = parse("line.ply", &ply_mesh(enc, &SQUARE, &[vec![0.0, 1.0]]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("at least 3"), "{e}");
        let full = ply_mesh(enc, &SQUARE, &[vec![0.0, 1.0, 2.0]]);
        let e = parse("cut.ply", &full[..full.len() - 12])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("cut.ply") && e.contains("face 0 (0-based)"),
            "{e}"
        );
    }
    let e = parse("ascii.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 oops\n3 0 1 2\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("ascii.ply, line 12: vertex 2") && e.contains("`oops` is not a number"),
        "{e}"
    );
    let e = parse("noz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("no `z` property"), "{e}");
    let e = parse("pts.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n")
        .unwrap_err();
    assert!(matches!(e, MeshError::Empty { .. }), "{e:?}");
}

#[test]
fn ply_hostile_counts_fail_fast() {
    let hostile = b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 4000000000\nproperty list uint uint vertex_indices\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0";
    let t = std::time::Instant::now();
    let e = parse("hostile.ply", hostile).unwrap_err().to_string();
    assert!(
        e.contains("hostile.ply") && e.contains("claims 4000000000 entries"),
        "{e}"
    );
    assert!(t.elapsed().as_secs_f64() < 0.1);
    // A face list of 4 billion indices.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n".to_vec();
    b.extend_from_slice(&[0; 36]);
    b.extend_from_slice(&u32::MAX.to_le_bytes());
    b.extend_from_slice(&[0; 12]);
    let e = parse("list.ply", &b).unwrap_err().to_string();
    assert!(
        e.contains("face 0") && e.contains("runs past the end"),
        "{e}"
    );
}

#[test]
fn gzipped_input_by_suffix_or_magic() {
    for (name, bytes) in [
        ("cube.obj.gz", CUBE_OBJ.as_bytes().to_vec()),
        ("two.stl.gz", binary_stl(b"", &TWO_TRIS)),
        (
            "square.ply.gz",
            ply_mesh(Encoding::BinaryBigEndian, &SQUARE, &[vec![0.0, 1.0, 2.0]]),
        ),
    ] {
        let plain = parse(name.trim_end_matches(".gz"), &bytes).unwrap();
        let (m, r) = parse(name, &gz(&bytes)).unwrap();
        assert!(r.gzipped && !plain.1.gzipped);
        assert_eq!(m, plain.0, "{name}");
        // No extension: detected from the decompressed content.
        assert_eq!(parse("stdin", &gz(&bytes)).unwrap().0, plain.0, "{name}");
    }
    assert_eq!(
        detect_format("x", &gz(CUBE_OBJ.as_bytes())),
        Some(MeshFormat::Obj)
    );
    let mut bad = gz(CUBE_OBJ.as_bytes());
    let n = bad.len();
    bad.truncate(n / 2);
    let e = parse("cube.obj.gz", &bad).unwrap_err();
    assert!(
        matches!(e, MeshError::Decompress { .. })
            && e.to_string().starts_with("cube.obj.gz: corrupt gzip"),
        "{e}"
    );
}

#[test]
fn decompression_is_capped() {
    let zeros = gz(&vec![0u8; 100_000]);
    assert_eq!(gunzip(&zeros, 100_000).unwrap().len(), 100_000);
    let e = gunzip(&zeros, 99_999).unwrap_err();
    assert!(e.contains("more than 99999 bytes"), "{e}");
}

#[test]
fn format_detection() {
    assert_eq!(detect_format("a.OBJ", b""), Some(MeshFormat::Obj));
    assert_eq!(detect_format("a.stl.GZ", b""), Some(MeshFormat::Stl));
    assert_eq!(
        detect_format("dir.ply/a.obj", b"ply\n"),
        Some(MeshFormat::Obj)
    );
    assert_eq!(
        detect_format("x", b"# hi\nv 1 2 3\n"),
        Some(MeshFormat::Obj)
    );
    assert_eq!(detect_format("x", b"  solid foo\n"), Some(MeshFormat::Stl));
    assert_eq!(detect_format("x", b"hello"), None);
    let e = parse("mystery.bin", b"hello").unwrap_err();
    assert!(
        matches!(e, MeshError::UnknownFormat { .. })
            && e.to_string().starts_with("mystery.bin: unknown"),
        "{e}"
    );
}

#[test]
fn load_mesh_io_error_names_the_file() {
    let e = load_mesh(Path::new("/nonexistent/dir/mesh.obj")).unwrap_err();
    assert!(matches!(e, MeshError::Io { .. }));
    assert!(
        e.to_string()
            .starts_with("/nonexistent/dir/mesh.obj: cannot read"),
        "{e}"
    );
}

#[test]
fn degenerate_triangles_are_kept() {
    let (m, _) = parse("d.obj", b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\nf 1 1 1\n").unwrap();
    assert_eq!(m.triangles.len(), 2);
}

#[test]
fn random_and_mutated_inputs_never_panic() {
    let mut seeds: Vec<Vec<u8>> = vec![
        CUBE_OBJ.as_bytes().to_vec(),
        b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n".to_vec(),
        binary_stl(b"solid", &TWO_TRIS),
        binary_stl(b"", &TWO_TRIS),
    ];
    for enc in [
        Encoding::Ascii,
        Encoding::BinaryLittleEndian,
        Encoding::BinaryBigEndian,
    ] {
        seeds.push(ply_mesh(
            enc,
            &SQUARE,
            &[vec![0.0, 1.0, 2.0, 3.0], vec![3.0, 2.0, 1.0]],
        ));
    }
    seeds.push(gz(CUBE_OBJ.as_bytes()));
    seeds.push(gz(&seeds[4].clone()));
    let mut rng = crate::io::ply::fuzz::Rng::new(0x9e37_79b9_7f4a_7c15);
    let names = ["m.obj", "m.stl", "m.ply", "m", "m.obj.gz"];
    let formats = [
        None,
        Some(MeshFormat::Obj),
        Some(MeshFormat::Stl),
        Some(MeshFormat::Ply),
    ];
    let mut ok = 0;
    for i in 0..crate::io::ply::fuzz::iterations() {
        let seed = &seeds[i % seeds.len()];
        let input = rng.mutate(seed);
        let name = names[i % names.len()];
        for f in formats {
            if let Ok((m, _)) = parse_mesh(name, &input, f) {
                ok += 1;
                assert!(!m.triangles.is_empty());
                assert!(m
                    .triangles
                    .iter()
                    .flatten()
                    .all(|&v| (v as usize) < m.positions.len()));
                assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
            }
        }
    }
    // Some mutations are harmless: the parsers did real work, not only reject.
    assert!(ok > 100, "{ok}");
}

/// The real meshes in ../shared/meshes (next to the repository), with the counts their
/// README lists.
#[test]
fn shared_meshes_load_with_the_listed_counts() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes");
    if !dir.is_dir() {
        assert_ne!(
            std::env::var("CI").as_deref(),
            Ok("true"),
            "CI=true needs {}",
            dir.display()
        );
        println!("skipped: ../shared/meshes not found");
        return;
    }
    let readme = std::fs::read_to_string(dir.join("README.md")).unwrap();
    let mut checked = 0;
    for row in readme
        .lines()
        .filter(|l| l.starts_with("| ") && l.contains(".obj.gz"))
    {
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        let count = |s: &str| s.replace(',', "").parse::<usize>().unwrap();
        let (file, vertices, triangles) = (cells[1], count(cells[2]), count(cells[3]));
        let (m, r) = load_mesh(&dir.join(file)).unwrap_or_else(|e| panic!("{e}"));
        assert!(r.gzipped);
        assert_eq!(
            (m.positions.len(), m.triangles.len()),
            (vertices, triangles),
            "{file}"
        );
        checked += 1;
    }
    assert!(checked >= 9, "only {checked} meshes listed");
}

#[test]
fn ascii_ply_entry_errors_name_the_entrys_own_line() {
    // Header lines 1-9, body from line 10: vertices on 10, 11, 12, the face on 13.
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                  property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                  end_header\n";
    let cases = [
        ("0 0 0\n1 0 0\n0 inf 0\n3 0 1 2\n", "line 12"),
        ("0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "line 13"),
        ("0 0 0\n1 0 0\n0 1 0\n2 0 1\n", "line 13"),
    ];
    for (body, line) in cases {
        let e = parse("entry.ply", format!("{header}{body}").as_bytes())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(&format!("entry.ply, {line}")),
            "{body:?}: {e}"
        );
    }
}
