//! Wavefront OBJ meshes: `v` and `f` statements (every face form, negative indices, forward
//! references, backslash continuations); everything else is skipped and counted.

use super::{fan, parse_error, three_floats, tokens, LoadReport, Mesh, MeshError, MAX_VERTICES};

/// The line without its continuation backslash (and the spaces around it), if it has one.
fn continues(line: &[u8]) -> Option<&[u8]> {
    let end = line.iter().rposition(|b| !b.is_ascii_whitespace())?;
    line[..=end].strip_suffix(b"\\")
}

pub(super) fn parse_obj(
    name: &str,
    data: &[u8],
    report: &mut LoadReport,
) -> Result<Mesh, MeshError> {
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
