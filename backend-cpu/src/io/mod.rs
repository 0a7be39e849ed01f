//! Files in and out: triangle meshes in Wavefront OBJ ([`obj`]), STL, ascii and binary
//! ([`stl`]), and PLY, ascii and binary of either endianness ([`ply`]), each optionally
//! gzipped ([`gzip`]); particle point clouds in PLY, in and out ([`particles`]).
//!
//! Polygons are triangulated as fans. Degenerate (zero-area) triangles are kept: the
//! builder skips and counts those. Every error names the file and says what is wrong (with
//! a line number for text formats where it helps); nothing panics on any input, and no
//! count from a file is trusted before it is checked against the bytes that are left.

use std::borrow::Cow;
use std::io::Read as _;
use std::path::Path;

use crate::bake::MeshRef;

pub mod gzip;
pub mod obj;
pub mod particles;
pub mod ply;
pub mod stl;

use gzip::gunzip;
pub use gzip::{is_gzip, MAX_DECOMPRESSED_BYTES};
pub use particles::{
    encode_particles, parse_particles, read_particles, write_particles, ExtraProperties,
    ParticleCloud, ParticleIoError, PlyEncoding,
};

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
    if stl::stl_binary_size(bytes).is_some_and(|(_, need)| need == bytes.len() as u64) {
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
        MeshFormat::Obj => obj::parse_obj(name, &data, &mut report)?,
        MeshFormat::Stl => stl::parse_stl(name, &data, &mut report)?,
        MeshFormat::Ply => ply::parse_ply(name, &data, &mut report)?,
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

#[cfg(test)]
mod tests;
