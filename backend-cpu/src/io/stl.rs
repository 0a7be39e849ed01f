//! STL meshes, binary and ascii (told apart by the size a binary header implies, not by a
//! leading `solid`); vertices are welded by bit pattern so that triangles share indices.

use std::collections::HashMap;

use super::{fan, parse_error, three_floats, tokens, LoadReport, Mesh, MeshError, MAX_VERTICES};

/// For data that could be a binary STL: its triangle count and the file size that count
/// needs.
pub(super) fn stl_binary_size(data: &[u8]) -> Option<(u32, u64)> {
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

pub(super) fn parse_stl(
    name: &str,
    data: &[u8],
    report: &mut LoadReport,
) -> Result<Mesh, MeshError> {
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
