//! Reading triangle meshes: PLY (ascii and binary), OBJ and STL (ascii and binary), each
//! optionally gzipped. Polygons are triangulated as fans. Every error names the file and
//! says what is wrong; nothing panics on input, and no count is trusted before it is checked
//! against the bytes left.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use crate::build::MeshRef;
use crate::ply::{self, PropertyKind};

/// A triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
}

impl<'a> From<&'a Mesh> for MeshRef<'a> {
    fn from(m: &'a Mesh) -> Self {
        MeshRef { positions: &m.positions, triangles: &m.triangles }
    }
}

/// A mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ.
    Obj,
    /// STL, ascii or binary.
    Stl,
    /// PLY, ascii or binary.
    Ply,
}

/// What loading found besides the mesh.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadReport {
    /// Polygons with more than three vertices, triangulated as fans.
    pub polygons_triangulated: usize,
    /// Whether the file was gzipped.
    pub gzipped: bool,
}

/// Why a mesh could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The contents are malformed.
    #[error("{path}{}: {message}", line.map(|l| format!(" line {l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: String,
        /// The line, for text formats.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A face uses a vertex that does not exist.
    #[error("{path}: face {face} uses vertex {index}, but there are {vertices} vertices")]
    IndexOutOfRange {
        /// The file.
        path: String,
        /// Which face (0-based).
        face: usize,
        /// The index as written (1-based for OBJ).
        index: i64,
        /// Number of vertices.
        vertices: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("{path}: vertex {vertex} has a NaN or infinite coordinate")]
    NonFinite {
        /// The file.
        path: String,
        /// Which vertex (0-based).
        vertex: usize,
    },
    /// No triangles.
    #[error("{path}: the mesh has no triangles")]
    Empty {
        /// The file.
        path: String,
    },
    /// Not a mesh format we know.
    #[error("{path}: unknown mesh format (expected .ply, .obj or .stl, optionally .gz)")]
    UnknownFormat {
        /// The file.
        path: String,
    },
}

/// Largest decompressed size accepted.
pub const MAX_DECOMPRESSED: u64 = 4 << 30;

/// Decompresses when the bytes are gzipped (by magic), with a size cap.
pub fn maybe_gunzip<'a>(name: &str, bytes: &'a [u8]) -> Result<(std::borrow::Cow<'a, [u8]>, bool), String> {
    if bytes.len() >= 2 && bytes[0] == 0x1f && bytes[1] == 0x8b {
        let mut out = Vec::new();
        let mut dec = flate2::read::MultiGzDecoder::new(bytes).take(MAX_DECOMPRESSED + 1);
        dec.read_to_end(&mut out).map_err(|e| format!("{name}: bad gzip data: {e}"))?;
        if out.len() as u64 > MAX_DECOMPRESSED {
            return Err(format!("{name}: decompresses to more than {MAX_DECOMPRESSED} bytes"));
        }
        Ok((std::borrow::Cow::Owned(out), true))
    } else {
        Ok((std::borrow::Cow::Borrowed(bytes), false))
    }
}

/// Reads a mesh file.
pub fn load_mesh(path: &Path) -> Result<(Mesh, LoadReport), MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io { path: name.clone(), source })?;
    parse_mesh(&name, &bytes, None)
}

/// The format named by a file name's extension (ignoring `.gz`), else guessed from content.
pub fn detect_format(name: &str, bytes: &[u8]) -> Option<MeshFormat> {
    let lower = name.to_ascii_lowercase();
    let stem = lower.strip_suffix(".gz").unwrap_or(&lower);
    if stem.ends_with(".ply") {
        return Some(MeshFormat::Ply);
    }
    if stem.ends_with(".obj") {
        return Some(MeshFormat::Obj);
    }
    if stem.ends_with(".stl") {
        return Some(MeshFormat::Stl);
    }
    if bytes.starts_with(b"ply") {
        return Some(MeshFormat::Ply);
    }
    if bytes.starts_with(b"solid") || stl_binary_count(bytes).is_some() {
        return Some(MeshFormat::Stl);
    }
    let head = &bytes[..bytes.len().min(4096)];
    if head.split(|&b| b == b'\n').any(|l| l.starts_with(b"v ") || l.starts_with(b"f ")) {
        return Some(MeshFormat::Obj);
    }
    None
}

/// Parses a mesh from bytes; `name` is used in errors and, with `format` `None`, to detect it.
pub fn parse_mesh(name: &str, bytes: &[u8], format: Option<MeshFormat>) -> Result<(Mesh, LoadReport), MeshError> {
    let parse_err = |line: Option<usize>, message: String| MeshError::Parse { path: name.to_string(), line, message };
    let (data, gzipped) = maybe_gunzip(name, bytes).map_err(|m| parse_err(None, m))?;
    let format = format
        .or_else(|| detect_format(name, &data))
        .ok_or_else(|| MeshError::UnknownFormat { path: name.to_string() })?;
    let mut report = LoadReport { gzipped, ..LoadReport::default() };
    let mesh = match format {
        MeshFormat::Obj => parse_obj(name, &data, &mut report)?,
        MeshFormat::Stl => parse_stl(name, &data)?,
        MeshFormat::Ply => parse_ply(name, &data, &mut report)?,
    };
    if let Some(vertex) = mesh.positions.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(MeshError::NonFinite { path: name.to_string(), vertex });
    }
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty { path: name.to_string() });
    }
    Ok((mesh, report))
}

fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>, report: &mut LoadReport) {
    if poly.len() > 3 {
        report.polygons_triangulated += 1;
    }
    for i in 1..poly.len().saturating_sub(1) {
        out.push([poly[0], poly[i], poly[i + 1]]);
    }
}

fn parse_obj(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let err = |line: usize, message: String| MeshError::Parse { path: name.to_string(), line: Some(line), message };
    let text = String::from_utf8_lossy(data);
    let mut mesh = Mesh::default();
    let mut poly: Vec<u32> = Vec::new();
    let mut faces = 0usize;
    for (n, line) in text.lines().enumerate() {
        let lineno = n + 1;
        let line = line.split('#').next().unwrap_or("").trim();
        let mut t = line.split_whitespace();
        match t.next() {
            Some("v") => {
                let mut p = [0.0f32; 3];
                for c in &mut p {
                    let tok = t.next().ok_or_else(|| err(lineno, "vertex needs three coordinates".into()))?;
                    *c = tok.parse().map_err(|_| err(lineno, format!("{tok:?} is not a number")))?;
                }
                mesh.positions.push(p);
            }
            Some("f") => {
                poly.clear();
                for tok in t {
                    let idx = tok.split('/').next().unwrap_or("");
                    let i: i64 = idx.parse().map_err(|_| err(lineno, format!("{tok:?} is not a vertex index")))?;
                    let count = mesh.positions.len() as i64;
                    let resolved = if i > 0 { i - 1 } else { count + i };
                    if i == 0 || resolved < 0 || resolved >= count {
                        return Err(MeshError::IndexOutOfRange {
                            path: name.to_string(),
                            face: faces,
                            index: i,
                            vertices: mesh.positions.len(),
                        });
                    }
                    poly.push(resolved as u32);
                }
                if poly.len() < 3 {
                    return Err(err(lineno, format!("face has {} vertices; at least 3 are needed", poly.len())));
                }
                fan(&poly, &mut mesh.triangles, report);
                faces += 1;
            }
            _ => {}
        }
    }
    Ok(mesh)
}

fn stl_binary_count(data: &[u8]) -> Option<usize> {
    let c = data.get(80..84)?;
    let n = u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as usize;
    (n.checked_mul(50)?.checked_add(84)? == data.len()).then_some(n)
}

fn parse_stl(name: &str, data: &[u8]) -> Result<Mesh, MeshError> {
    let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
    let mut mesh = Mesh::default();
    let mut vertex = |p: [f32; 3], mesh: &mut Mesh| -> u32 {
        *weld.entry(p.map(f32::to_bits)).or_insert_with(|| {
            mesh.positions.push(p);
            (mesh.positions.len() - 1) as u32
        })
    };
    if let Some(n) = stl_binary_count(data) {
        for i in 0..n {
            let rec = &data[84 + 50 * i..84 + 50 * (i + 1)];
            let f = |k: usize| f32::from_le_bytes([rec[k], rec[k + 1], rec[k + 2], rec[k + 3]]);
            let mut t = [0u32; 3];
            for (j, ti) in t.iter_mut().enumerate() {
                let o = 12 + 12 * j;
                *ti = vertex([f(o), f(o + 4), f(o + 8)], &mut mesh);
            }
            mesh.triangles.push(t);
        }
        return Ok(mesh);
    }
    if !data.starts_with(b"solid") {
        return Err(MeshError::Parse {
            path: name.to_string(),
            line: None,
            message: "not an ascii STL (no `solid`) and not a binary STL (size does not match its triangle count)".into(),
        });
    }
    let text = String::from_utf8_lossy(data);
    let mut corners: Vec<u32> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let mut t = line.split_whitespace();
        match t.next() {
            Some("vertex") => {
                let mut p = [0.0f32; 3];
                for c in &mut p {
                    let tok = t.next().unwrap_or("");
                    *c = tok.parse().map_err(|_| MeshError::Parse {
                        path: name.to_string(),
                        line: Some(n + 1),
                        message: format!("{tok:?} is not a number"),
                    })?;
                }
                corners.push(vertex(p, &mut mesh));
            }
            Some("endloop") => {
                if corners.len() < 3 {
                    return Err(MeshError::Parse {
                        path: name.to_string(),
                        line: Some(n + 1),
                        message: format!("facet has {} vertices; at least 3 are needed", corners.len()),
                    });
                }
                fan(&corners, &mut mesh.triangles, &mut LoadReport::default());
                corners.clear();
            }
            _ => {}
        }
    }
    Ok(mesh)
}

fn parse_ply(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let err = |message: String| MeshError::Parse { path: name.to_string(), line: None, message };
    let header = ply::parse_header(data).map_err(err)?;
    let mut body = ply::Body::new(data, &header);
    let mut mesh = Mesh::default();
    let mut poly: Vec<u32> = Vec::new();
    for el in &header.elements {
        body.check_fits(el).map_err(err)?;
        match el.name.as_str() {
            "vertex" => {
                let find = |n: &str| el.properties.iter().position(|p| p.name == n);
                let (Some(x), Some(y), Some(z)) = (find("x"), find("y"), find("z")) else {
                    return Err(err("vertex element lacks x, y or z".into()));
                };
                mesh.positions.reserve(el.count);
                for _ in 0..el.count {
                    let mut p = [0.0f32; 3];
                    for (k, prop) in el.properties.iter().enumerate() {
                        match prop.kind {
                            PropertyKind::Scalar(s) if k == x || k == y || k == z => {
                                let v = body.scalar(s).map_err(err)? as f32;
                                p[if k == x { 0 } else if k == y { 1 } else { 2 }] = v;
                            }
                            kind => body.skip(kind).map_err(err)?,
                        }
                    }
                    mesh.positions.push(p);
                }
            }
            "face" => {
                let list = el
                    .properties
                    .iter()
                    .position(|p| (p.name == "vertex_indices" || p.name == "vertex_index") && matches!(p.kind, PropertyKind::List { .. }))
                    .ok_or_else(|| err("face element has no vertex_indices list".into()))?;
                for face in 0..el.count {
                    for (k, prop) in el.properties.iter().enumerate() {
                        match prop.kind {
                            PropertyKind::List { count, item } if k == list => {
                                let n = body.list_len(count, item).map_err(err)?;
                                poly.clear();
                                for _ in 0..n {
                                    let i = body.scalar(item).map_err(err)?;
                                    if !(i >= 0.0) || i >= mesh.positions.len() as f64 || i.fract() != 0.0 {
                                        return Err(MeshError::IndexOutOfRange {
                                            path: name.to_string(),
                                            face,
                                            index: if i.is_finite() { i as i64 } else { -1 },
                                            vertices: mesh.positions.len(),
                                        });
                                    }
                                    poly.push(i as u32);
                                }
                                if poly.len() < 3 {
                                    return Err(err(format!("face {face} has {} vertices; at least 3 are needed", poly.len())));
                                }
                                fan(&poly, &mut mesh.triangles, report);
                            }
                            kind => body.skip(kind).map_err(err)?,
                        }
                    }
                }
            }
            _ => {
                for _ in 0..el.count {
                    for prop in &el.properties {
                        body.skip(prop.kind).map_err(err)?;
                    }
                }
            }
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use std::io::Write;

    use super::*;

    const QUAD_OBJ: &str = "# a quad and a triangle\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\nf -4/1/1 -3/2/1 -1/3/1\n";

    #[test]
    fn obj_quads_slashes_and_negative_indices() {
        let (m, r) = parse_mesh("q.obj", QUAD_OBJ.as_bytes(), None).unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 3]]);
        assert_eq!(r.polygons_triangulated, 1);
    }

    #[test]
    fn gzip_is_detected_by_magic() {
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        enc.write_all(QUAD_OBJ.as_bytes()).unwrap();
        let gz = enc.finish().unwrap();
        let (m, r) = parse_mesh("q.obj.gz", &gz, None).unwrap();
        assert!(r.gzipped);
        assert_eq!(m.triangles.len(), 3);
    }

    #[test]
    fn stl_ascii_and_binary_agree() {
        let ascii = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n\
facet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n";
        let (a, _) = parse_mesh("t.stl", ascii.as_bytes(), None).unwrap();
        assert_eq!(a.positions.len(), 4, "shared corners are welded");
        let mut bin = vec![0u8; 80];
        bin.extend_from_slice(&2u32.to_le_bytes());
        for tri in [[[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]] {
            bin.extend_from_slice(&[0u8; 12]);
            for v in tri {
                for c in v {
                    bin.extend_from_slice(&c.to_le_bytes());
                }
            }
            bin.extend_from_slice(&[0u8; 2]);
        }
        let (b, _) = parse_mesh("t.stl", &bin, None).unwrap();
        assert_eq!(a, b);
        // A binary file whose size disagrees with its count, not starting with `solid`.
        assert!(parse_mesh("t.stl", &bin[..bin.len() - 1], None).is_err());
    }

    #[test]
    fn ply_ascii_and_binary_with_extra_elements() {
        let ascii = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n\
element face 1\nproperty list uchar int vertex_indices\nelement edge 1\nproperty int a\nproperty int b\nend_header\n\
0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n4 0 1 2 3\n0 1\n";
        let (a, r) = parse_mesh("a.ply", ascii.as_bytes(), None).unwrap();
        assert_eq!(a.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(r.polygons_triangulated, 1);
        let mut bin = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_index\nend_header\n".to_vec();
        for v in [[0.0f64, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
            for c in v {
                bin.extend_from_slice(&c.to_be_bytes());
            }
        }
        bin.push(3);
        for i in [0u32, 1, 2] {
            bin.extend_from_slice(&i.to_be_bytes());
        }
        let (b, _) = parse_mesh("b.ply", &bin, None).unwrap();
        assert_eq!(b.positions[1], [1.0, 0.0, 0.0]);
        assert_eq!(b.triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn errors_name_the_file_and_the_problem() {
        let cases: &[(&str, &str, &str)] = &[
            ("a.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "vertex 4, but there are 3"),
            ("b.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 1 has a NaN"),
            ("c.obj", "v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
            ("d.obj", "v 0 0 0\n", "no triangles"),
            ("e.obj", "v 0 0\n", "line 1"),
            ("f.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n", "at least 3"),
            ("g.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n", "claims"),
            ("h.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "vertex 7"),
            ("i.xyz", "hello", "unknown mesh format"),
        ];
        for (name, text, needle) in cases {
            let e = parse_mesh(name, text.as_bytes(), None).unwrap_err().to_string();
            assert!(e.starts_with(name), "{e}");
            assert!(e.contains(needle), "{name}: expected {needle:?} in {e:?}");
        }
    }

    #[test]
    fn mutated_and_truncated_bytes_never_panic() {
        let seeds: Vec<Vec<u8>> = vec![
            QUAD_OBJ.as_bytes().to_vec(),
            b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".iter().copied().chain([0u8; 36]).chain([3u8, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]).collect(),
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n".to_vec(),
        ];
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for seed in &seeds {
            for _ in 0..1500 {
                let mut b = seed.clone();
                match next() % 3 {
                    0 => b.truncate((next() as usize) % (b.len() + 1)),
                    1 => {
                        for _ in 0..1 + next() % 4 {
                            let i = next() as usize % b.len();
                            b[i] = next() as u8;
                        }
                    }
                    _ => {
                        let i = next() as usize % b.len();
                        b.insert(i, next() as u8);
                    }
                }
                for fmt in [None, Some(MeshFormat::Obj), Some(MeshFormat::Ply), Some(MeshFormat::Stl)] {
                    let _ = parse_mesh("fuzz", &b, fmt);
                }
                let _ = crate::particles::parse_particles("fuzz", &b);
            }
        }
    }
}
