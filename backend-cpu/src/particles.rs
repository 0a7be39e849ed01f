//! Particle point clouds in PLY: `x y z`, optionally `vx vy vz`, `side` and `flags`, and any
//! other scalar vertex properties, which are carried through unchanged.

use std::path::Path;

use octoproxy_core::Particle;

use crate::mesh::maybe_gunzip;
use crate::ply::{self, PropertyKind, Scalar};

/// Other vertex properties of a particle file, kept as they were.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExtraProperties {
    /// Names and types, in file order.
    pub properties: Vec<(String, Scalar)>,
    /// Values, `properties.len()` per particle, exact for every type.
    pub values: Vec<f64>,
}

/// Particles and what came with them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleCloud {
    /// The particles, in file order.
    pub particles: Vec<Particle>,
    /// Whether the file carried `side`; when not, callers initialise it from the proxy.
    pub has_side: bool,
    /// Other vertex properties.
    pub extra: ExtraProperties,
}

impl ParticleCloud {
    /// A cloud of particles with no extra properties.
    pub fn from_particles(particles: Vec<Particle>) -> Self {
        ParticleCloud { particles, has_side: true, extra: ExtraProperties::default() }
    }
}

/// How to write a particle file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Text.
    Ascii,
    /// Binary, little-endian.
    BinaryLittleEndian,
}

/// Why a particle file could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ParticleIoError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The contents are malformed or unsupported.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// Reads a particle file (`.ply`, optionally gzipped).
pub fn read_particles(path: &Path) -> Result<ParticleCloud, ParticleIoError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ParticleIoError::Io { path: name.clone(), source })?;
    parse_particles(&name, &bytes)
}

/// Parses a particle file from bytes; `name` is used in errors.
pub fn parse_particles(name: &str, bytes: &[u8]) -> Result<ParticleCloud, ParticleIoError> {
    let err = |message: String| ParticleIoError::Parse { path: name.to_string(), message };
    let (data, _) = maybe_gunzip(name, bytes).map_err(|m| ParticleIoError::Parse { path: name.to_string(), message: m })?;
    let header = ply::parse_header(&data).map_err(err)?;
    let Some(vertex) = header.elements.iter().find(|e| e.name == "vertex") else {
        return Err(err("no vertex element".into()));
    };
    if let Some(other) = header.elements.iter().find(|e| e.name != "vertex") {
        return Err(err(format!("element {:?} is not supported in particle files (only vertex)", other.name)));
    }
    let find = |n: &str| vertex.properties.iter().position(|p| p.name == n);
    for axis in ["x", "y", "z"] {
        if find(axis).is_none() {
            return Err(err(format!("vertex element lacks the property {axis}")));
        }
    }
    let vel = [find("vx"), find("vy"), find("vz")];
    let has_velocity = vel.iter().all(Option::is_some);
    if !has_velocity && vel.iter().any(Option::is_some) {
        return Err(err("give all of vx, vy, vz or none".into()));
    }
    // Role of each property: 0..3 position, 3..6 velocity, 6 side, 7 flags, 8 extra.
    let mut roles = Vec::new();
    let mut extra = ExtraProperties::default();
    for p in &vertex.properties {
        let PropertyKind::Scalar(ty) = p.kind else {
            return Err(err(format!("list property {:?} is not supported in particle files", p.name)));
        };
        let role = match p.name.as_str() {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            "vx" => 3,
            "vy" => 4,
            "vz" => 5,
            "side" => 6,
            "flags" => 7,
            _ => {
                extra.properties.push((p.name.clone(), ty));
                8
            }
        };
        roles.push((role, ty));
    }
    let mut body = ply::Body::new(&data, &header);
    body.check_fits(vertex).map_err(err)?;
    let mut particles = Vec::with_capacity(vertex.count);
    extra.values.reserve(vertex.count * extra.properties.len());
    for i in 0..vertex.count {
        let mut p = Particle::default();
        for &(role, ty) in &roles {
            let v = body.scalar(ty).map_err(|m| err(format!("vertex {i}: {m}")))?;
            match role {
                0..=2 => p.position[role] = v as f32,
                3..=5 => p.velocity[role - 3] = v as f32,
                6 => p.side = if v == 1.0 { 1 } else { 0 },
                7 => p.flags = v as u32,
                _ => extra.values.push(v),
            }
        }
        particles.push(p);
    }
    Ok(ParticleCloud { particles, has_side: find("side").is_some(), extra })
}

/// Encodes a particle file: `x y z vx vy vz side flags`, then the extra properties.
pub fn encode_particles(cloud: &ParticleCloud, encoding: PlyEncoding) -> Vec<u8> {
    let ascii = encoding == PlyEncoding::Ascii;
    let mut out = Vec::new();
    let mut header = format!(
        "ply\nformat {} 1.0\ncomment written by octoproxy\nelement vertex {}\n",
        if ascii { "ascii" } else { "binary_little_endian" },
        cloud.particles.len()
    );
    for n in ["x", "y", "z", "vx", "vy", "vz"] {
        header.push_str(&format!("property float {n}\n"));
    }
    header.push_str("property uint side\nproperty uint flags\n");
    for (n, ty) in &cloud.extra.properties {
        header.push_str(&format!("property {} {n}\n", ty.name()));
    }
    header.push_str("end_header\n");
    out.extend_from_slice(header.as_bytes());
    let k = cloud.extra.properties.len();
    for (i, p) in cloud.particles.iter().enumerate() {
        let mut first = true;
        let mut put = |out: &mut Vec<u8>, ty: Scalar, v: f64| {
            if ascii && !first {
                out.push(b' ');
            }
            first = false;
            ply::write_scalar(out, ascii, ty, v);
        };
        for c in p.position.iter().chain(p.velocity.iter()) {
            put(&mut out, Scalar::F32, *c as f64);
        }
        put(&mut out, Scalar::U32, p.side as f64);
        put(&mut out, Scalar::U32, p.flags as f64);
        for (j, (_, ty)) in cloud.extra.properties.iter().enumerate() {
            let v = cloud.extra.values.get(i * k + j).copied().unwrap_or(0.0);
            put(&mut out, *ty, v);
        }
        if ascii {
            out.push(b'\n');
        }
    }
    out
}

/// Writes a particle file through a temporary file in the same directory, so a failed write
/// never leaves half a file.
pub fn write_particles(path: &Path, cloud: &ParticleCloud, encoding: PlyEncoding) -> Result<(), ParticleIoError> {
    let name = path.display().to_string();
    let io = |source| ParticleIoError::Io { path: name.clone(), source };
    let bytes = encode_particles(cloud, encoding);
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> ParticleCloud {
        let mut c = ParticleCloud::from_particles(vec![
            Particle { position: [1.5, -2.25, 1e-7], side: 1, velocity: [0.1, 0.2, -0.3], flags: 5 << 8 },
            Particle { position: [f32::MAX, 0.0, -0.0], side: 0, velocity: [0.0; 3], flags: 1 },
        ]);
        c.extra = ExtraProperties {
            properties: vec![("id".into(), Scalar::I32), ("temp".into(), Scalar::F64), ("tag".into(), Scalar::U8)],
            values: vec![-7.0, 0.123456789012345, 200.0, 8.0, -1e300, 3.0],
        };
        c
    }

    #[test]
    fn round_trips_in_both_encodings() {
        for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
            let c = cloud();
            let back = parse_particles("t.ply", &encode_particles(&c, enc)).unwrap();
            assert_eq!(back, c, "{enc:?}");
        }
    }

    #[test]
    fn minimal_and_big_endian_files() {
        let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty double x\nproperty float y\nproperty float z\nend_header\n".to_vec();
        for v in [1.0f64, 2.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
            bytes.extend_from_slice(&(v as f32 * 10.0).to_be_bytes());
            bytes.extend_from_slice(&(-v as f32).to_be_bytes());
        }
        let c = parse_particles("be.ply", &bytes).unwrap();
        assert!(!c.has_side);
        assert_eq!(c.particles[1].position, [2.0, 20.0, -2.0]);
        assert_eq!(c.particles[1].velocity, [0.0; 3]);
    }

    #[test]
    fn bad_files_are_errors() {
        let noz = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n";
        let e = parse_particles("noz.ply", noz.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("noz.ply") && e.contains("lacks the property z"), "{e}");
        let partial_v = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float vx\nend_header\n0 0 0 1\n";
        assert!(parse_particles("v.ply", partial_v.as_bytes()).is_err());
        let hostile = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        let e = parse_particles("h.ply", hostile.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("claims"), "{e}");
        let truncated = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5\n";
        assert!(parse_particles("t.ply", truncated.as_bytes()).is_err());
    }
}
