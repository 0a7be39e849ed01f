//! Particle point clouds in PLY files, in and out.
//!
//! A particle file is a PLY file (ascii or binary, either endianness, optionally gzipped)
//! with one element, `vertex`, whose properties are `x y z` (required), `vx vy vz`
//! (velocity in units per second; all three or none), `side` and `flags` (optional, any
//! integer type; `side` is 0 (front) or 1 (back), plus 128 and exit bits for a particle still
//! caged in the solid leaf it started in, as `Particle::side` holds it: 128–255, and 256 more
//! for one in a solid leaf's slab), and any
//! other scalar properties, which are carried through unchanged:
//! same names, types, values and order. Files are written with `x y z vx vy vz side flags`
//! (float ×6, uint ×2) first, then the other properties.
//!
//! NaN or infinite positions are read as they are: the step flags them.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use octoproxy_core::{Particle, SIDE_CAGED, SIDE_CAGE_MASK, SIDE_EXITS_MASK, SIDE_MASK, SIDE_SLAB};

use super::gzip::{gunzip, MAX_DECOMPRESSED_BYTES};
use crate::io::ply::{self, Element, Encoding, PlyError, Property, PropertyKind, Scalar};

/// The properties every written file starts with, in this order.
const STANDARD: [(&str, Scalar); 8] = [
    ("x", Scalar::F32),
    ("y", Scalar::F32),
    ("z", Scalar::F32),
    ("vx", Scalar::F32),
    ("vy", Scalar::F32),
    ("vz", Scalar::F32),
    ("side", Scalar::U32),
    ("flags", Scalar::U32),
];

/// The vertex properties of a particle file other than the standard ones, kept as they were.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExtraProperties {
    /// Names and types, in file order.
    pub properties: Vec<(String, Scalar)>,
    /// The values, particle by particle: `properties.len()` per particle, in the order of
    /// `properties`. An `f64` holds every PLY scalar type exactly.
    pub values: Vec<f64>,
}

impl ExtraProperties {
    /// Number of extra properties.
    pub fn len(&self) -> usize {
        self.properties.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.properties.is_empty()
    }

    /// The extra values of particle `i`, in the order of `properties`.
    pub fn row(&self, i: usize) -> Option<&[f64]> {
        let k = self.properties.len();
        let start = i.checked_mul(k)?;
        self.values.get(start..start.checked_add(k)?)
    }
}

/// Particles, and what else their file carried.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleCloud {
    /// The particles, in file order.
    pub particles: Vec<Particle>,
    /// Whether the file carried `side`; when it did not, every side is
    /// [`SIDE_FRONT`](octoproxy_core::SIDE_FRONT) and the caller initialises them (from the
    /// mesh, or the proxy).
    pub has_side: bool,
    /// The other vertex properties, carried through unchanged.
    pub extra: ExtraProperties,
}

impl ParticleCloud {
    /// A cloud of new particles with no extra properties. `has_side` is `false`: their sides
    /// are to be initialised by the caller, as for a file without `side`.
    pub fn from_particles(particles: Vec<Particle>) -> Self {
        ParticleCloud {
            particles,
            has_side: false,
            extra: ExtraProperties::default(),
        }
    }
}

/// How [`write_particles`] and [`encode_particles`] encode the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlyEncoding {
    /// Text; floats are written so that they read back exactly.
    Ascii,
    /// Binary, little-endian (the default).
    #[default]
    BinaryLittleEndian,
}

/// Why a particle file could not be read or written. Every message starts with the file name.
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
    /// The file is gzipped, and the gzip data is corrupt or decompresses to too much.
    #[error("{path}: {message}")]
    Decompress {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The contents are malformed.
    #[error("{path}{}: {message}", line.map(|l| format!(", line {l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: String,
        /// The line (1-based), for ascii files.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A required vertex property is missing.
    #[error(
        "{path}: the vertex element has no `{property}` property (particle files need x, y and z)"
    )]
    MissingProperty {
        /// The file.
        path: String,
        /// The missing property.
        property: String,
    },
    /// The file uses something particle files do not support.
    #[error("{path}: {what} is not supported in particle files (only a `vertex` element with scalar properties)")]
    Unsupported {
        /// The file.
        path: String,
        /// What is not supported.
        what: String,
    },
    /// The cloud given to [`write_particles`] is inconsistent.
    #[error("{path}: cannot write these particles: {message}")]
    InvalidCloud {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// Reads a particle file (`.ply`, or gzipped `.ply.gz`).
pub fn read_particles(path: &Path) -> Result<ParticleCloud, ParticleIoError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ParticleIoError::Io {
        path: name.clone(),
        source,
    })?;
    parse_particles(&name, &bytes)
}

/// What a vertex property of a particle file holds.
#[derive(Clone, Copy)]
enum Role {
    Position(usize),
    Velocity(usize),
    Side,
    Flags,
    Extra,
}

/// Parses a particle file from its bytes (gzipped or not); `name` is used in error messages.
pub fn parse_particles(name: &str, bytes: &[u8]) -> Result<ParticleCloud, ParticleIoError> {
    let data =
        gunzip(bytes, MAX_DECOMPRESSED_BYTES).map_err(|message| ParticleIoError::Decompress {
            path: name.to_string(),
            message,
        })?;
    let parse_err = |line: Option<usize>, message: String| ParticleIoError::Parse {
        path: name.to_string(),
        line,
        message,
    };
    let ply_err = |e: PlyError| parse_err(e.line, e.message);
    let unsupported = |what: String| ParticleIoError::Unsupported {
        path: name.to_string(),
        what,
    };
    let header = ply::parse_header(&data).map_err(ply_err)?;
    if let Some(other) = header.elements.iter().find(|e| e.name != "vertex") {
        return Err(unsupported(format!("the element `{}`", other.name)));
    }
    let vertex = header
        .element("vertex")
        .ok_or_else(|| parse_err(None, "the file has no vertex element".into()))?;

    let missing = |property: &str| ParticleIoError::MissingProperty {
        path: name.to_string(),
        property: property.into(),
    };
    for axis in ["x", "y", "z"] {
        vertex.find(axis).ok_or_else(|| missing(axis))?;
    }
    let velocity: Vec<&str> = ["vx", "vy", "vz"]
        .into_iter()
        .filter(|v| vertex.find(v).is_some())
        .collect();
    if !velocity.is_empty() && velocity.len() < 3 {
        return Err(parse_err(
            None,
            format!(
                "the vertex element has {} but not all of vx, vy, vz: give all three or none",
                velocity.join(", ")
            ),
        ));
    }

    let mut roles = Vec::with_capacity(vertex.properties.len());
    let mut extra = ExtraProperties::default();
    for p in &vertex.properties {
        let PropertyKind::Scalar(ty) = p.kind else {
            return Err(unsupported(format!(
                "the list property `{}` of the vertex element",
                p.name
            )));
        };
        let role = match p.name.as_str() {
            "x" => Role::Position(0),
            "y" => Role::Position(1),
            "z" => Role::Position(2),
            "vx" => Role::Velocity(0),
            "vy" => Role::Velocity(1),
            "vz" => Role::Velocity(2),
            "side" | "flags" if !ty.is_integer() => {
                return Err(parse_err(
                    None,
                    format!(
                        "the property `{}` must have an integer type, not {}",
                        p.name,
                        ty.name()
                    ),
                ))
            }
            "side" => Role::Side,
            "flags" => Role::Flags,
            _ => {
                extra.properties.push((p.name.clone(), ty));
                Role::Extra
            }
        };
        roles.push((role, ty));
    }

    let mut r = ply::Reader::new(&data, &header);
    r.check_fits(vertex).map_err(ply_err)?;
    let mut particles = Vec::with_capacity(vertex.count);
    extra
        .values
        .reserve(vertex.count.saturating_mul(extra.properties.len()));
    for i in 0..vertex.count {
        let at = |e: PlyError| parse_err(e.line, format!("vertex {i} (0-based): {}", e.message));
        let mut p = Particle::default();
        for &(role, ty) in &roles {
            let line = r.next_value_line();
            let v = r.scalar(ty).map_err(at)?;
            match role {
                Role::Position(k) => {
                    if let Some(c) = p.position.get_mut(k) {
                        *c = v as f32;
                    }
                }
                Role::Velocity(k) => {
                    if let Some(c) = p.velocity.get_mut(k) {
                        *c = v as f32;
                    }
                }
                Role::Side => {
                    // 0 or 1, or a caged particle's side: the cage bit, any exits, and the slab
                    // bit of one in a solid leaf's slab.
                    let word = v as u32;
                    let valid = f64::from(word) == v
                        && (word <= SIDE_MASK
                            || (word & SIDE_CAGED != 0
                                && word & !(SIDE_CAGE_MASK | SIDE_MASK) == 0
                                && (word & SIDE_SLAB == 0
                                    || (word & SIDE_EXITS_MASK).count_ones() == 1)));
                    if !valid {
                        return Err(parse_err(
                            line,
                            format!("vertex {i} (0-based): side is {v}; it must be 0 (front) or 1 (back), or 128-255 for a particle caged in the solid leaf it started in (384-511, with one exit, in a solid leaf's slab)"),
                        ));
                    }
                    p.side = word;
                }
                Role::Flags => {
                    if !(0.0..=f64::from(u32::MAX)).contains(&v) {
                        return Err(parse_err(
                            line,
                            format!(
                                "vertex {i} (0-based): flags {v} is not a 32-bit unsigned value"
                            ),
                        ));
                    }
                    p.flags = v as u32;
                }
                Role::Extra => extra.values.push(v),
            }
        }
        particles.push(p);
    }
    Ok(ParticleCloud {
        particles,
        has_side: vertex.find("side").is_some(),
        extra,
    })
}

/// Checks that a cloud can be written faithfully: extra names that are valid, distinct and
/// not standard, and one value per particle and extra property.
fn check_cloud(cloud: &ParticleCloud) -> Result<(), String> {
    let extra = &cloud.extra;
    let mut seen = std::collections::HashSet::new();
    for (name, _) in &extra.properties {
        if name.is_empty() || name.chars().any(char::is_whitespace) {
            return Err(format!(
                "the extra property name {name:?} is empty or holds whitespace"
            ));
        }
        if STANDARD.iter().any(|(s, _)| s == name) {
            return Err(format!(
                "the extra property `{name}` clashes with a standard one"
            ));
        }
        if !seen.insert(name) {
            return Err(format!("the extra property `{name}` is given twice"));
        }
    }
    let need = cloud.particles.len().checked_mul(extra.properties.len());
    if need != Some(extra.values.len()) {
        return Err(format!(
            "{} extra values for {} particles with {} extra properties",
            extra.values.len(),
            cloud.particles.len(),
            extra.properties.len()
        ));
    }
    Ok(())
}

/// Encodes a particle file: `x y z vx vy vz side flags` (float ×6, uint ×2), then the extra
/// properties in their order and types. Every particle is written, in order. A cloud with
/// missing extra values gets zeros for them ([`write_particles`] refuses such a cloud).
pub fn encode_particles(cloud: &ParticleCloud, encoding: PlyEncoding) -> Vec<u8> {
    let encoding = match encoding {
        PlyEncoding::Ascii => Encoding::Ascii,
        PlyEncoding::BinaryLittleEndian => Encoding::BinaryLittleEndian,
    };
    let properties = STANDARD
        .iter()
        .map(|(n, s)| (n.to_string(), *s))
        .chain(cloud.extra.properties.iter().cloned())
        .map(|(name, s)| Property {
            name,
            kind: PropertyKind::Scalar(s),
        })
        .collect();
    let vertex = Element {
        name: "vertex".into(),
        count: cloud.particles.len(),
        properties,
    };
    let mut w = ply::Writer::new(encoding, &[vertex], &["particles written by octoproxy"]);
    for (i, p) in cloud.particles.iter().enumerate() {
        for c in p.position.iter().chain(&p.velocity) {
            w.scalar(Scalar::F32, f64::from(*c));
        }
        w.scalar(Scalar::U32, f64::from(p.side));
        w.scalar(Scalar::U32, f64::from(p.flags));
        let k = cloud.extra.properties.len();
        for (j, (_, ty)) in cloud.extra.properties.iter().enumerate() {
            let at = i.checked_mul(k).and_then(|r| r.checked_add(j));
            let v = at
                .and_then(|a| cloud.extra.values.get(a))
                .copied()
                .unwrap_or(0.0);
            w.scalar(*ty, v);
        }
        w.end_entry();
    }
    w.finish()
}

/// Writes a particle file (gzipped when the name ends in `.gz`). The bytes go to a temporary
/// file in the same directory, which is then renamed over `path`, so a failed write never
/// leaves half a file.
pub fn write_particles(
    path: &Path,
    cloud: &ParticleCloud,
    encoding: PlyEncoding,
) -> Result<(), ParticleIoError> {
    let name = path.display().to_string();
    check_cloud(cloud).map_err(|message| ParticleIoError::InvalidCloud {
        path: name.clone(),
        message,
    })?;
    let io = |source| ParticleIoError::Io {
        path: name.clone(),
        source,
    };
    let mut bytes = encode_particles(cloud, encoding);
    if name.to_ascii_lowercase().ends_with(".gz") {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(&bytes).map_err(io)?;
        bytes = gz.finish().map_err(io)?;
    }
    let Some(file_name) = path.file_name() else {
        return Err(ParticleIoError::InvalidCloud {
            path: name,
            message: "the path names no file".into(),
        });
    };
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    tmp_name.push(format!(".tmp{}", std::process::id()));
    let tmp: PathBuf = path.with_file_name(tmp_name);
    let written = std::fs::write(&tmp, &bytes).and_then(|()| std::fs::rename(&tmp, path));
    if let Err(source) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(source));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use octoproxy_core::{FLAG_INVALID, SIDE_BACK, SIDE_FRONT};

    /// Particles and extras that exercise every type and awkward values.
    fn cloud() -> ParticleCloud {
        let particles = vec![
            Particle {
                position: [1.5, -2.25, 1e-7],
                side: SIDE_BACK,
                velocity: [0.1, 0.2, -0.3],
                flags: 5 << 8,
            },
            Particle {
                position: [f32::MAX, 0.0, -0.0],
                side: SIDE_FRONT,
                velocity: [0.0; 3],
                flags: u32::MAX,
            },
            Particle {
                position: [f32::NAN, f32::INFINITY, f32::MIN_POSITIVE / 8.0],
                side: SIDE_FRONT,
                velocity: [f32::NEG_INFINITY, 1.0 / 3.0, -1e30],
                flags: FLAG_INVALID,
            },
        ];
        use Scalar::*;
        let properties = [
            ("id", I32),
            ("temperature", F64),
            ("tag", U8),
            ("small", I8),
            ("short", I16),
            ("ushort", U16),
            ("big", U32),
            ("mass", F32),
        ];
        let values = vec![
            -7.0,
            0.123456789012345,
            200.0,
            -128.0,
            -32768.0,
            65535.0,
            4294967295.0,
            0.1f32 as f64, //
            2147483647.0,
            -1e300,
            0.0,
            127.0,
            32767.0,
            0.0,
            0.0,
            1e-40f32 as f64, //
            -2147483648.0,
            f64::INFINITY,
            255.0,
            0.0,
            0.0,
            1.0,
            1.0,
            -0.0,
        ];
        ParticleCloud {
            particles,
            has_side: true,
            extra: ExtraProperties {
                properties: properties
                    .iter()
                    .map(|(n, t)| (n.to_string(), *t))
                    .collect(),
                values,
            },
        }
    }

    /// Bit-exact comparison (NaN included).
    fn assert_same(a: &ParticleCloud, b: &ParticleCloud) {
        assert_eq!(a.particles.len(), b.particles.len());
        for (p, q) in a.particles.iter().zip(&b.particles) {
            assert_eq!(
                bytemuck::bytes_of(p),
                bytemuck::bytes_of(q),
                "{p:?} vs {q:?}"
            );
        }
        assert_eq!(a.has_side, b.has_side);
        assert_eq!(a.extra.properties, b.extra.properties);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.extra.values), bits(&b.extra.values));
    }

    #[test]
    fn round_trips_in_both_encodings() {
        for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
            let c = cloud();
            let bytes = encode_particles(&c, enc);
            let back = parse_particles("t.ply", &bytes).unwrap();
            assert_same(&back, &c);
            // And again: a file we wrote from a file we read is the same file.
            assert_eq!(encode_particles(&back, enc), bytes);
        }
    }

    #[test]
    fn written_header_has_the_standard_order_then_the_extras() {
        let text = String::from_utf8(encode_particles(&cloud(), PlyEncoding::Ascii)).unwrap();
        let props: Vec<&str> = text.lines().filter(|l| l.starts_with("property")).collect();
        assert_eq!(
            props[..10],
            [
                "property float x",
                "property float y",
                "property float z",
                "property float vx",
                "property float vy",
                "property float vz",
                "property uint side",
                "property uint flags",
                "property int id",
                "property double temperature",
            ]
        );
        assert!(text.starts_with("ply\nformat ascii 1.0\n"));
        assert!(text.contains("element vertex 3\n"));
        let bin = encode_particles(&cloud(), PlyEncoding::default());
        assert!(bin.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    }

    #[test]
    fn write_and_read_files_through_a_rename() {
        let dir = std::env::temp_dir().join(format!("octoproxy-particles-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (file, enc) in [
            ("a.ply", PlyEncoding::Ascii),
            ("b.ply", PlyEncoding::BinaryLittleEndian),
            ("c.ply.gz", PlyEncoding::Ascii),
        ] {
            let path = dir.join(file);
            write_particles(&path, &cloud(), enc).unwrap();
            assert_same(&read_particles(&path).unwrap(), &cloud());
            // Overwriting works too.
            let small =
                ParticleCloud::from_particles(vec![Particle::new([1.0, 2.0, 3.0], [0.0; 3])]);
            write_particles(&path, &small, enc).unwrap();
            let back = read_particles(&path).unwrap();
            assert_eq!(back.particles, small.particles);
            assert!(back.has_side);
        }
        let gz = std::fs::read(dir.join("c.ply.gz")).unwrap();
        assert_eq!(&gz[..2], &[0x1f, 0x8b]);
        let mut names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            ["a.ply", "b.ply", "c.ply.gz"],
            "no temporary files left"
        );

        // A failed write leaves nothing, and names the file.
        let bad = dir.join("missing-dir").join("x.ply");
        let e = write_particles(&bad, &cloud(), PlyEncoding::Ascii).unwrap_err();
        assert!(
            matches!(e, ParticleIoError::Io { .. }) && e.to_string().contains("x.ply"),
            "{e}"
        );
        let e = read_particles(&dir.join("nope.ply")).unwrap_err();
        assert!(e.to_string().contains("nope.ply"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn inconsistent_clouds_are_not_written() {
        let path = std::env::temp_dir().join("octoproxy-never-written.ply");
        let mut c = cloud();
        c.extra.values.pop();
        let e = write_particles(&path, &c, PlyEncoding::Ascii)
            .unwrap_err()
            .to_string();
        assert!(e.contains("23 extra values for 3 particles"), "{e}");
        let mut c = cloud();
        c.extra.properties[0].0 = "side".into();
        assert!(write_particles(&path, &c, PlyEncoding::Ascii).is_err());
        let mut c = cloud();
        c.extra.properties[0].0 = "two words".into();
        assert!(write_particles(&path, &c, PlyEncoding::Ascii).is_err());
        let mut c = cloud();
        c.extra.properties[1].0 = "id".into();
        assert!(write_particles(&path, &c, PlyEncoding::Ascii).is_err());
        assert!(!path.exists());
        // encode_particles itself never drops particles, even for such a cloud.
        let mut c = cloud();
        c.extra.values.truncate(5);
        let back = parse_particles(
            "t.ply",
            &encode_particles(&c, PlyEncoding::BinaryLittleEndian),
        )
        .unwrap();
        assert_eq!(back.particles.len(), 3);
        assert_eq!(&back.extra.values[..5], &c.extra.values[..]);
        assert!(back.extra.values[5..].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn big_endian_doubles_and_small_integer_types() {
        let mut b = b"ply\nformat binary_big_endian 1.0\ncomment hi\nelement vertex 2\nproperty double x\nproperty short id\nproperty float y\nproperty float z\nproperty uchar side\nproperty ushort flags\nend_header\n".to_vec();
        for (i, v) in [1.0f64, 2.0].iter().enumerate() {
            b.extend_from_slice(&v.to_be_bytes());
            b.extend_from_slice(&(-(i as i16) - 1).to_be_bytes());
            b.extend_from_slice(&(*v as f32 * 10.0).to_be_bytes());
            b.extend_from_slice(&(-*v as f32).to_be_bytes());
            b.push(i as u8);
            b.extend_from_slice(&(300u16 + i as u16).to_be_bytes());
        }
        let c = parse_particles("be.ply", &b).unwrap();
        assert!(c.has_side);
        assert_eq!(c.particles[1].position, [2.0, 20.0, -2.0]);
        assert_eq!(c.particles[1].velocity, [0.0; 3]);
        assert_eq!(
            [c.particles[0].side, c.particles[1].side],
            [SIDE_FRONT, SIDE_BACK]
        );
        assert_eq!([c.particles[0].flags, c.particles[1].flags], [300, 301]);
        assert_eq!(c.extra.properties, vec![("id".to_string(), Scalar::I16)]);
        assert_eq!(c.extra.values, vec![-1.0, -2.0]);
        assert_eq!(c.extra.row(1), Some(&[-2.0][..]));
        assert_eq!(c.extra.row(2), None);
    }

    #[test]
    fn ascii_with_velocity_nan_and_gzip() {
        let text = "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float vz\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nproperty float vx\r\nproperty float vy\r\nproperty int8 k\r\nend_header\r\n3 nan 1 2 1 2 -5\r\n-0.5 inf -inf 1e-45 0 0 5\r\n";
        let c = parse_particles("v.ply", text.as_bytes()).unwrap();
        assert!(!c.has_side);
        assert!(c.particles[0].position[0].is_nan());
        assert_eq!(c.particles[0].velocity, [1.0, 2.0, 3.0]);
        assert_eq!(
            c.particles[1].position,
            [f32::INFINITY, f32::NEG_INFINITY, 1e-45]
        );
        assert_eq!(c.particles[1].velocity, [0.0, 0.0, -0.5]);
        assert_eq!(c.extra.values, vec![-5.0, 5.0]);
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(text.as_bytes()).unwrap();
        let z = parse_particles("v.ply.gz", &gz.finish().unwrap()).unwrap();
        assert_same(&z, &c);
    }

    #[test]
    fn bad_files_are_errors_that_say_why() {
        let head = "ply\nformat ascii 1.0\nelement vertex 1\n";
        let cases: &[(&str, &str)] = &[
            ("property float x\nproperty float y\nend_header\n0 0\n", "has no `z` property"),
            ("property float y\nproperty float z\nend_header\n0 0\n", "has no `x` property"),
            (
                "property float x\nproperty float y\nproperty float z\nproperty float vx\nproperty float vz\nend_header\n0 0 0 1 1\n",
                "has vx, vz but not all of vx, vy, vz",
            ),
            (
                "property float x\nproperty float y\nproperty float z\nproperty list uchar int n\nend_header\n0 0 0 0\n",
                "the list property `n` of the vertex element is not supported in particle files",
            ),
            (
                "property float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n",
                "the element `face` is not supported",
            ),
            ("property float x\nproperty float y\nproperty float z\nproperty float side\nend_header\n0 0 0 0\n", "`side` must have an integer type"),
            ("property float x\nproperty float y\nproperty float z\nproperty int side\nend_header\n0 0 0 2\n", "line 9: vertex 0 (0-based): side is 2"),
            ("property float x\nproperty float y\nproperty float z\nproperty int side\nend_header\n0 0 0 256\n", "side is 256; it must be 0 (front) or 1 (back), or 128-255"),
            ("property float x\nproperty float y\nproperty float z\nproperty int side\nend_header\n0 0 0 -1\n", "side is -1"),
            ("property float x\nproperty float y\nproperty float z\nproperty int flags\nend_header\n0 0 0 -1\n", "flags -1 is not a 32-bit unsigned value"),
            ("property float x\nproperty float y\nproperty float z\nend_header\n0 0 zero\n", "line 8: vertex 0 (0-based): `zero` is not a number"),
            ("property float x\nproperty float y\nproperty float z\nend_header\n0 0          \n", "unexpected end of data"),
            ("property float x\nproperty float y\nproperty float z\nend_header\n0 0\n", "claims 1 entries"),
        ];
        for (rest, want) in cases {
            let e = parse_particles("p.ply", format!("{head}{rest}").as_bytes())
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("p.ply") && e.contains(want), "{rest:?}: {e}");
        }
        let e = parse_particles("q.ply", b"ply\nformat ascii 1.0\nend_header\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("q.ply: the file has no vertex element"), "{e}");
        let e = parse_particles("r.ply", b"not a ply")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "r.ply, line 1: not a PLY file (the first line is not `ply`)"
        );
        let e = parse_particles("s.ply", b"ply\nformat ascii 1.0\n")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "s.ply: the header has no end_header line");
    }

    #[test]
    fn hostile_counts_and_truncated_binary() {
        let hostile = b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        let t = std::time::Instant::now();
        let e = parse_particles("h.ply", hostile).unwrap_err().to_string();
        assert!(
            e.contains("h.ply") && e.contains("claims 4000000000 entries"),
            "{e}"
        );
        assert!(t.elapsed().as_secs_f64() < 0.1);
        let full = encode_particles(&cloud(), PlyEncoding::BinaryLittleEndian);
        let e = parse_particles("cut.ply", &full[..full.len() - 3])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cut.ply") && e.contains("claims 3 entries, more than the 171 bytes left"),
            "{e}"
        );
    }

    #[test]
    fn random_and_mutated_inputs_never_panic() {
        let mut small = cloud();
        small.particles.truncate(2);
        small.extra.values.truncate(16);
        let mut seeds = vec![
            encode_particles(&small, PlyEncoding::Ascii),
            encode_particles(&small, PlyEncoding::BinaryLittleEndian),
            b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\nproperty double y\nproperty double z\nproperty uchar side\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\x01".to_vec(),
        ];
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(&seeds[0]).unwrap();
        seeds.push(gz.finish().unwrap());
        let mut rng = crate::io::ply::fuzz::Rng::new(0x2545_f491_4f6c_dd1d);
        let mut ok = 0;
        for i in 0..crate::io::ply::fuzz::iterations() {
            let input = rng.mutate(&seeds[i % seeds.len()]);
            if let Ok(c) = parse_particles("fuzz.ply", &input) {
                ok += 1;
                assert_eq!(c.extra.values.len(), c.particles.len() * c.extra.len());
                // Whatever we read, we can write and read back.
                let again = parse_particles("again.ply", &encode_particles(&c, PlyEncoding::Ascii))
                    .unwrap();
                assert_eq!(again.particles.len(), c.particles.len());
            }
        }
        assert!(ok > 100, "{ok}");
    }

    #[test]
    fn a_caged_particle_keeps_its_cage_through_a_file() {
        use octoproxy_core::{side_exit, SIDE_CAGED};
        let mut p = Particle::new([0.5, 0.25, 0.0], [1.0, 0.0, 0.0]);
        p.side = SIDE_BACK | SIDE_CAGED | side_exit(1, true) | side_exit(2, false);
        for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
            let bytes = encode_particles(&ParticleCloud::from_particles(vec![p]), enc);
            let back = parse_particles("caged.ply", &bytes).expect("a caged side reads back");
            assert_eq!(back.particles[0].side, p.side, "{enc:?}");
            assert!(back.particles[0].is_caged());
            assert_eq!(back.particles[0].side_only(), SIDE_BACK);
        }
    }
}
