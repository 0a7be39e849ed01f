//! Reading triangle meshes: Wavefront OBJ, STL (ascii and binary) and PLY (ascii and
//! binary, either endianness), each optionally gzipped.
//!
//! Polygons are triangulated as fans. Degenerate (zero-area) triangles are kept: the
//! builder skips and counts those. Every error names the file and says what is wrong (with
//! a line number for text formats where it helps); nothing panics on any input, and no
//! count from a file is trusted before it is checked against the bytes that are left.

use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use crate::build::MeshRef;
use crate::ply::{self, PlyError, PropertyKind};

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
        MeshRef {
            positions: &m.positions,
            triangles: &m.triangles,
        }
    }
}

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ.
    Obj,
    /// STL, ascii or binary.
    Stl,
    /// PLY, ascii or binary.
    Ply,
}

/// What loading found besides the mesh.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LoadReport {
    /// Polygons with more than three vertices, triangulated as fans.
    pub polygons_triangulated: usize,
    /// Whether the file was gzipped.
    pub gzipped: bool,
}

/// Why a mesh could not be read. Every message starts with the file name.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read.
    #[error("{path}: cannot read the file: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is gzipped, and the gzip data is corrupt or decompresses to too much.
    #[error("{path}: {message}")]
    Decompress {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The contents are malformed.
    #[error("{}: {message}", place(.path, *.line))]
    Parse {
        /// The file.
        path: String,
        /// The line (1-based), for text formats.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "{}: face {face} (0-based) refers to vertex {index}, but the file has {vertices} vertices",
        place(.path, *.line)
    )]
    IndexOutOfRange {
        /// The file.
        path: String,
        /// The line (1-based) of the face, for text formats.
        line: Option<usize>,
        /// Which face (0-based, counting faces as written, before triangulation).
        face: usize,
        /// The index as written in the file (OBJ: 1-based, or negative = relative).
        index: i64,
        /// How many vertices there are (OBJ negative indices: defined before the face).
        vertices: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{}: vertex {vertex} (0-based) has a NaN or infinite coordinate", place(.path, *.line))]
    NonFinite {
        /// The file.
        path: String,
        /// The line (1-based) of the vertex, for text formats.
        line: Option<usize>,
        /// Which vertex (0-based).
        vertex: usize,
    },
    /// The file holds no triangles.
    #[error("{path}: the mesh is empty (no triangles)")]
    Empty {
        /// The file.
        path: String,
    },
    /// Not a mesh format we read.
    #[error("{path}: unknown mesh format (expected PLY, OBJ or STL: name the file .ply, .obj or .stl, optionally .gz)")]
    UnknownFormat {
        /// The file.
        path: String,
    },
}

fn place(path: &str, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{path}, line {l}"),
        None => path.to_string(),
    }
}

/// Largest decompressed size accepted from a gzipped file (4 GiB).
pub const MAX_DECOMPRESSED_BYTES: u64 = 4 << 30;

/// Whether `bytes` start with the gzip magic bytes `1f 8b`.
pub fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// Decompresses `bytes` when they are gzipped (by their magic bytes, whatever the name),
/// refusing more than `limit` decompressed bytes; returns them unchanged otherwise. Running
/// out of memory is an error too, not an abort. The error is a message.
pub(crate) fn gunzip(bytes: &[u8], limit: u64) -> Result<Cow<'_, [u8]>, String> {
    if !is_gzip(bytes) {
        return Ok(Cow::Borrowed(bytes));
    }
    let mut decoder = flate2::read::MultiGzDecoder::new(bytes);
    let mut out: Vec<u8> = Vec::new();
    let mut chunk = vec![0u8; 1 << 16];
    loop {
        let n = match decoder.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(format!("corrupt gzip data: {e}")),
        };
        if (out.len() + n) as u64 > limit {
            return Err(format!("gzip data decompresses to more than {limit} bytes"));
        }
        out.try_reserve(n)
            .map_err(|_| format!("out of memory after decompressing {} bytes", out.len()))?;
        out.extend_from_slice(chunk.get(..n).unwrap_or_default());
    }
    Ok(Cow::Owned(out))
}

/// Reads a mesh file (`.obj`, `.stl`, `.ply`, each optionally `.gz`).
pub fn load_mesh(path: &Path) -> Result<(Mesh, LoadReport), MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: name.clone(),
        source,
    })?;
    parse_mesh(&name, &bytes, None)
}

/// The format of a mesh file: from the extension of `name` (ignoring a `.gz` suffix, any
/// case), else from the content (`bytes` may be gzipped).
pub fn detect_format(name: &str, bytes: &[u8]) -> Option<MeshFormat> {
    let lower = name.to_ascii_lowercase();
    let stem = lower.strip_suffix(".gz").unwrap_or(&lower);
    for (ext, format) in [
        (".ply", MeshFormat::Ply),
        (".obj", MeshFormat::Obj),
        (".stl", MeshFormat::Stl),
    ] {
        if stem.ends_with(ext) {
            return Some(format);
        }
    }
    if is_gzip(bytes) {
        // Look at the start of the decompressed data only.
        let mut head = Vec::new();
        let _ = flate2::read::MultiGzDecoder::new(bytes)
            .take(1 << 16)
            .read_to_end(&mut head);
        return detect_content(&head);
    }
    detect_content(bytes)
}

fn detect_content(bytes: &[u8]) -> Option<MeshFormat> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some(MeshFormat::Ply);
    }
    if stl_binary_size(bytes).is_some_and(|(_, need)| need == bytes.len() as u64) {
        return Some(MeshFormat::Stl);
    }
    if bytes.trim_ascii_start().starts_with(b"solid") {
        return Some(MeshFormat::Stl);
    }
    let head = bytes.get(..1 << 16).unwrap_or(bytes);
    let is_obj_line = |l: &[u8]| {
        let l = l.trim_ascii_start();
        (l.starts_with(b"v ") || l.starts_with(b"v\t") || l.starts_with(b"f ")) && !l.contains(&0)
    };
    if head.split(|&b| b == b'\n').any(is_obj_line) {
        return Some(MeshFormat::Obj);
    }
    None
}

/// Parses a mesh from the bytes of a file (gzipped or not). `name` is used in error messages
/// and, when `format` is `None`, to detect the format from its extension; failing that the
/// format is detected from the content.
pub fn parse_mesh(
    name: &str,
    bytes: &[u8],
    format: Option<MeshFormat>,
) -> Result<(Mesh, LoadReport), MeshError> {
    let data = gunzip(bytes, MAX_DECOMPRESSED_BYTES).map_err(|message| MeshError::Decompress {
        path: name.to_string(),
        message,
    })?;
    let mut report = LoadReport {
        gzipped: matches!(data, Cow::Owned(_)),
        ..LoadReport::default()
    };
    let format = match format {
        Some(f) => f,
        None => detect_format(name, &data).ok_or_else(|| MeshError::UnknownFormat {
            path: name.to_string(),
        })?,
    };
    let mesh = match format {
        MeshFormat::Obj => parse_obj(name, &data, &mut report)?,
        MeshFormat::Stl => parse_stl(name, &data, &mut report)?,
        MeshFormat::Ply => parse_ply(name, &data, &mut report)?,
    };
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty {
            path: name.to_string(),
        });
    }
    Ok((mesh, report))
}

/// Appends the fan triangulation of `poly` (at least 3 vertices) to `out`.
fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>, report: &mut LoadReport) {
    if let [first, rest @ ..] = poly {
        if rest.len() > 2 {
            report.polygons_triangulated += 1;
        }
        for pair in rest.windows(2) {
            if let [b, c] = pair {
                out.push([*first, *b, *c]);
            }
        }
    }
}

/// The most vertices a mesh may have: indices are `u32`.
const MAX_VERTICES: usize = u32::MAX as usize;

fn parse_error(name: &str, line: Option<usize>, message: impl Into<String>) -> MeshError {
    MeshError::Parse {
        path: name.to_string(),
        line,
        message: message.into(),
    }
}

/// Splits a line into whitespace-separated tokens.
fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// Parses three coordinates from `t`; the error is a message.
fn three_floats<'a>(t: &mut impl Iterator<Item = &'a [u8]>) -> Result<[f32; 3], String> {
    let mut p = [0.0f32; 3];
    for c in &mut p {
        let tok = t.next().ok_or("a vertex needs three coordinates, x y z")?;
        let s = std::str::from_utf8(tok).unwrap_or_default();
        *c = s
            .parse()
            .map_err(|_| format!("`{}` is not a number", tok.escape_ascii()))?;
    }
    Ok(p)
}

/// The line without its continuation backslash (and the spaces around it), if it has one.
fn continues(line: &[u8]) -> Option<&[u8]> {
    let end = line.iter().rposition(|b| !b.is_ascii_whitespace())?;
    line[..=end].strip_suffix(b"\\")
}

fn parse_obj(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let mut mesh = Mesh::default();
    let mut poly: Vec<u32> = Vec::new();
    let mut faces = 0usize;
    // The largest positive index that referred past the vertices read so far (OBJ allows
    // forward references): (index, face, line). Checked once every vertex is read.
    let mut forward: Option<(i64, usize, usize)> = None;
    // A line that ends in a backslash continues on the next; errors name its first line.
    let mut joined: Vec<u8> = Vec::new();
    let mut lines = data.split(|&b| b == b'\n').enumerate();
    while let Some((n, raw)) = lines.next() {
        let lineno = n + 1;
        let mut logical = raw;
        if continues(raw).is_some() {
            joined.clear();
            let mut cur = raw;
            while let Some(head) = continues(cur) {
                joined.extend_from_slice(head);
                joined.push(b' ');
                match lines.next() {
                    Some((_, next)) => cur = next,
                    None => {
                        cur = &[];
                        break;
                    }
                }
            }
            joined.extend_from_slice(cur);
            logical = &joined;
        }
        let line = logical.split(|&b| b == b'#').next().unwrap_or_default();
        let mut t = tokens(line);
        match t.next() {
            Some(b"v") => {
                let p = three_floats(&mut t).map_err(|m| parse_error(name, Some(lineno), m))?;
                let vertex = mesh.positions.len();
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(MeshError::NonFinite {
                        path: name.to_string(),
                        line: Some(lineno),
                        vertex,
                    });
                }
                if vertex >= MAX_VERTICES {
                    return Err(parse_error(
                        name,
                        Some(lineno),
                        "more vertices than 32-bit indices can address",
                    ));
                }
                mesh.positions.push(p);
            }
            Some(b"f") => {
                poly.clear();
                let count = mesh.positions.len() as i64;
                for tok in t {
                    let first = tok.split(|&b| b == b'/').next().unwrap_or_default();
                    let s = std::str::from_utf8(first).unwrap_or_default();
                    let i: i64 = s.parse().map_err(|_| {
                        parse_error(
                            name,
                            Some(lineno),
                            format!("`{}` is not a vertex reference", tok.escape_ascii()),
                        )
                    })?;
                    let out_of_range = || MeshError::IndexOutOfRange {
                        path: name.to_string(),
                        line: Some(lineno),
                        face: faces,
                        index: i,
                        vertices: mesh.positions.len(),
                    };
                    let resolved = match i {
                        0 => return Err(out_of_range()),
                        i if i < 0 => count
                            .checked_add(i)
                            .filter(|r| *r >= 0)
                            .ok_or_else(out_of_range)?,
                        i => {
                            if i > count && forward.is_none_or(|(m, _, _)| i > m) {
                                forward = Some((i, faces, lineno));
                            }
                            i - 1
                        }
                    };
                    poly.push(u32::try_from(resolved).map_err(|_| out_of_range())?);
                }
                if poly.len() < 3 {
                    return Err(parse_error(
                        name,
                        Some(lineno),
                        format!(
                            "a face needs at least 3 vertices, this one has {}",
                            poly.len()
                        ),
                    ));
                }
                fan(&poly, &mut mesh.triangles, report);
                faces += 1;
            }
            _ => {}
        }
    }
    if let Some((index, face, line)) = forward {
        if index > mesh.positions.len() as i64 {
            return Err(MeshError::IndexOutOfRange {
                path: name.to_string(),
                line: Some(line),
                face,
                index,
                vertices: mesh.positions.len(),
            });
        }
    }
    Ok(mesh)
}

/// For data that could be a binary STL: its triangle count and the file size that count
/// needs.
fn stl_binary_size(data: &[u8]) -> Option<(u32, u64)> {
    let n = u32::from_le_bytes(data.get(80..84)?.try_into().ok()?);
    Some((n, 84 + 50 * u64::from(n)))
}

/// Merges vertices with identical bit patterns, so that triangles share indices.
#[derive(Default)]
struct Welder {
    map: HashMap<[u32; 3], u32>,
}

impl Welder {
    /// The index of `p` in `mesh`, added when new. Fails on NaN or infinite coordinates
    /// (`name` and `line` are for the error).
    fn vertex(
        &mut self,
        p: [f32; 3],
        mesh: &mut Mesh,
        name: &str,
        line: Option<usize>,
    ) -> Result<u32, MeshError> {
        let next = mesh.positions.len();
        if !p.iter().all(|c| c.is_finite()) {
            return Err(MeshError::NonFinite {
                path: name.to_string(),
                line,
                vertex: next,
            });
        }
        if let Some(&index) = self.map.get(&p.map(f32::to_bits)) {
            return Ok(index);
        }
        let index = u32::try_from(next)
            .ok()
            .filter(|_| next < MAX_VERTICES)
            .ok_or_else(|| {
                parse_error(name, line, "more vertices than 32-bit indices can address")
            })?;
        self.map.insert(p.map(f32::to_bits), index);
        mesh.positions.push(p);
        Ok(index)
    }
}

fn parse_stl(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let binary = stl_binary_size(data);
    if let Some((n, need)) = binary {
        if need == data.len() as u64 {
            return parse_stl_binary(name, data, n);
        }
    }
    let size_hint = match binary {
        Some((n, need)) => format!(
            "as a binary STL, its header says {n} triangles, which need {need} bytes, but the file has {} bytes",
            data.len()
        ),
        None => format!("it is too short for a binary STL ({} bytes, at least 84 needed)", data.len()),
    };
    if !data.trim_ascii_start().starts_with(b"solid") {
        return Err(parse_error(
            name,
            None,
            format!("not an STL file: it does not start with `solid` as an ascii STL does, and {size_hint}"),
        ));
    }
    parse_stl_ascii(name, data, report).map_err(|e| match e {
        // An ascii parse failure may be a binary STL whose header starts with "solid".
        MeshError::Parse {
            path,
            line,
            message,
        } if binary.is_some() => MeshError::Parse {
            path,
            line,
            message: format!("{message} (read as an ascii STL; {size_hint})"),
        },
        e => e,
    })
}

fn parse_stl_binary(name: &str, data: &[u8], n: u32) -> Result<Mesh, MeshError> {
    let mut mesh = Mesh::default();
    let mut weld = Welder::default();
    let records = data.get(84..).unwrap_or_default().chunks_exact(50);
    mesh.triangles.reserve(records.len());
    for rec in records.take(n as usize) {
        let mut t = [0u32; 3];
        for (j, ti) in t.iter_mut().enumerate() {
            let mut p = [0.0f32; 3];
            for (k, c) in p.iter_mut().enumerate() {
                let o = 12 + 12 * j + 4 * k;
                let b = rec
                    .get(o..o + 4)
                    .and_then(|b| b.try_into().ok())
                    .unwrap_or([0; 4]);
                *c = f32::from_le_bytes(b);
            }
            *ti = weld.vertex(p, &mut mesh, name, None)?;
        }
        mesh.triangles.push(t);
    }
    Ok(mesh)
}

fn parse_stl_ascii(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let mut mesh = Mesh::default();
    let mut weld = Welder::default();
    let mut corners: Vec<u32> = Vec::new();
    let mut in_loop = false;
    let mut last_line = 0;
    for (n, raw) in data.split(|&b| b == b'\n').enumerate() {
        let lineno = n + 1;
        let err = |m: String| parse_error(name, Some(lineno), m);
        let mut t = tokens(raw);
        let Some(keyword) = t.next() else { continue };
        last_line = lineno;
        match keyword {
            b"solid" | b"endsolid" | b"facet" | b"endfacet" if !in_loop => {}
            b"outer" if !in_loop => {
                if t.next() != Some(b"loop") {
                    return Err(err("expected `outer loop`".into()));
                }
                in_loop = true;
                corners.clear();
            }
            b"vertex" if in_loop => {
                let p = three_floats(&mut t).map_err(err)?;
                corners.push(weld.vertex(p, &mut mesh, name, Some(lineno))?);
            }
            b"endloop" if in_loop => {
                if corners.len() < 3 {
                    return Err(err(format!(
                        "a facet needs at least 3 vertices, this one has {}",
                        corners.len()
                    )));
                }
                fan(&corners, &mut mesh.triangles, report);
                in_loop = false;
            }
            other => {
                let where_ = if in_loop { "inside" } else { "outside" };
                return Err(err(format!(
                    "unexpected `{}` {where_} an `outer loop`",
                    other.get(..40).unwrap_or(other).escape_ascii()
                )));
            }
        }
    }
    if in_loop {
        return Err(parse_error(
            name,
            Some(last_line),
            "the file ends inside an `outer loop`",
        ));
    }
    Ok(mesh)
}

fn parse_ply(name: &str, data: &[u8], report: &mut LoadReport) -> Result<Mesh, MeshError> {
    let ply_err = |e: PlyError| MeshError::Parse {
        path: name.to_string(),
        line: e.line,
        message: e.message,
    };
    let header = ply::parse_header(data).map_err(ply_err)?;
    let plain = |m: String| parse_error(name, None, m);
    let vertex_el = header
        .element("vertex")
        .ok_or_else(|| plain("there is no vertex element".into()))?;
    let vertices = vertex_el.count;
    if vertices > MAX_VERTICES {
        return Err(plain(format!(
            "{vertices} vertices are more than 32-bit indices can address"
        )));
    }
    let mut axes = [0usize; 3];
    for (axis, slot) in ["x", "y", "z"].iter().zip(&mut axes) {
        *slot = vertex_el
            .find(axis)
            .ok_or_else(|| plain(format!("the vertex element has no `{axis}` property")))?;
        if !matches!(
            vertex_el.properties.get(*slot).map(|p| p.kind),
            Some(PropertyKind::Scalar(_))
        ) {
            return Err(plain(format!(
                "the vertex property `{axis}` is a list, not a number"
            )));
        }
    }
    let face_el = header.element("face").ok_or_else(|| MeshError::Empty {
        path: name.to_string(),
    })?;
    let list = face_el
        .properties
        .iter()
        .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
        .ok_or_else(|| plain("the face element has no `vertex_indices` property".into()))?;
    if !matches!(
        face_el.properties.get(list).map(|p| p.kind),
        Some(PropertyKind::List { .. })
    ) {
        return Err(plain(
            "the face property `vertex_indices` is not a list".into(),
        ));
    }

    let mut mesh = Mesh::default();
    let mut r = ply::Reader::new(data, &header);
    // Adds which entry of which element to a body error.
    let at = |el: &str, i: usize, e: PlyError| MeshError::Parse {
        path: name.to_string(),
        line: e.line,
        message: format!("{el} {i} (0-based): {}", e.message),
    };
    let mut poly: Vec<u32> = Vec::new();
    let mut items: Vec<f64> = Vec::new();
    for el in &header.elements {
        match el.name.as_str() {
            "vertex" => {
                r.check_fits(el).map_err(ply_err)?;
                mesh.positions.reserve(el.count);
                for i in 0..el.count {
                    let line = r.line();
                    let mut p = [0.0f32; 3];
                    for (k, prop) in el.properties.iter().enumerate() {
                        match (axes.iter().position(|&a| a == k), prop.kind) {
                            (Some(axis), PropertyKind::Scalar(s)) => {
                                let v = r.scalar(s).map_err(|e| at("vertex", i, e))?;
                                if let Some(c) = p.get_mut(axis) {
                                    *c = v as f32;
                                }
                            }
                            (_, kind) => r.skip(kind).map_err(|e| at("vertex", i, e))?,
                        }
                    }
                    if !p.iter().all(|c| c.is_finite()) {
                        return Err(MeshError::NonFinite {
                            path: name.to_string(),
                            line,
                            vertex: i,
                        });
                    }
                    mesh.positions.push(p);
                }
            }
            "face" => {
                r.check_fits(el).map_err(ply_err)?;
                for face in 0..el.count {
                    let line = r.line();
                    for (k, prop) in el.properties.iter().enumerate() {
                        let (true, PropertyKind::List { count, item }) = (k == list, prop.kind)
                        else {
                            r.skip(prop.kind).map_err(|e| at("face", face, e))?;
                            continue;
                        };
                        items.clear();
                        r.list(count, item, &mut items)
                            .map_err(|e| at("face", face, e))?;
                        poly.clear();
                        for &v in &items {
                            let ok = v >= 0.0 && v.fract() == 0.0 && v < vertices as f64;
                            if !ok {
                                return Err(MeshError::IndexOutOfRange {
                                    path: name.to_string(),
                                    line,
                                    face,
                                    // Saturating, and 0 for NaN: the message stays readable.
                                    index: v as i64,
                                    vertices,
                                });
                            }
                            poly.push(v as u32);
                        }
                        if poly.len() < 3 {
                            return Err(parse_error(
                                name,
                                line,
                                format!("face {face} (0-based) has {} vertices, a face needs at least 3", poly.len()),
                            ));
                        }
                        fan(&poly, &mut mesh.triangles, report);
                    }
                }
            }
            _ => r.skip_element(el).map_err(|e| at(&el.name, 0, e))?,
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ply::{Element, Encoding, Property, Scalar, Writer};
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
        let mut rng = crate::ply::fuzz::Rng::new(0x9e37_79b9_7f4a_7c15);
        let names = ["m.obj", "m.stl", "m.ply", "m", "m.obj.gz"];
        let formats = [
            None,
            Some(MeshFormat::Obj),
            Some(MeshFormat::Stl),
            Some(MeshFormat::Ply),
        ];
        let mut ok = 0;
        for i in 0..crate::ply::fuzz::iterations() {
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
}
