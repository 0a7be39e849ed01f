//! PLY: a small, self-contained reader and writer, shared by the mesh reader (this file's
//! `parse_ply`) and the particle files ([`crate::io::particles`]).
//!
//! Reading: [`parse_header`] parses the header (ascii, binary little- or big-endian; the
//! scalar types `char uchar short ushort int uint float double` and their `int8 ... float64`
//! aliases; scalar and list properties), then a [`Reader`] walks the body value by value.
//! Every value comes back as an `f64`, which holds every PLY scalar type exactly.
//!
//! The reader never panics on input, and it never trusts a count from the file: element
//! counts and list lengths are checked against the bytes that are left before anything is
//! allocated or looped over ([`Reader::check_fits`], [`Reader::list_len`]).
//!
//! Writing: a [`Writer`] writes the header for a list of [`Element`]s, then takes the values
//! entry by entry, in ascii or binary (either endianness).

use std::collections::HashSet;
use std::fmt::Write as _;

use super::{fan, parse_error, LoadReport, Mesh, MeshError, MAX_VERTICES};

/// Largest header accepted, in bytes; a file without `end_header` by then is not PLY.
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// What is wrong with a PLY file. The caller adds the file name.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{}{message}", line.map(|l| format!("line {l}: ")).unwrap_or_default())]
pub struct PlyError {
    /// The line (1-based, counting the header) for header errors and ascii bodies.
    pub line: Option<usize>,
    /// What is wrong.
    pub message: String,
}

impl PlyError {
    fn new(line: Option<usize>, message: impl Into<String>) -> Self {
        PlyError {
            line,
            message: message.into(),
        }
    }
}

/// A scalar type of a PLY property.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Scalar {
    /// `char` / `int8`.
    I8,
    /// `uchar` / `uint8`.
    U8,
    /// `short` / `int16`.
    I16,
    /// `ushort` / `uint16`.
    U16,
    /// `int` / `int32`.
    I32,
    /// `uint` / `uint32`.
    U32,
    /// `float` / `float32`.
    F32,
    /// `double` / `float64`.
    F64,
}

impl Scalar {
    /// The type named in a header (`uchar`, `uint8`, `float32`, ...), if it is one.
    pub fn from_name(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// The name this writer puts in headers (the classic names: `uchar`, `float`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }

    /// Size in bytes in binary bodies.
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Whether this is an integer type.
    pub fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The range of an integer type, as `i64`; `None` for the float types.
    pub fn int_range(self) -> Option<(i64, i64)> {
        Some(match self {
            Scalar::I8 => (i8::MIN.into(), i8::MAX.into()),
            Scalar::U8 => (0, u8::MAX.into()),
            Scalar::I16 => (i16::MIN.into(), i16::MAX.into()),
            Scalar::U16 => (0, u16::MAX.into()),
            Scalar::I32 => (i32::MIN.into(), i32::MAX.into()),
            Scalar::U32 => (0, u32::MAX.into()),
            Scalar::F32 | Scalar::F64 => return None,
        })
    }
}

/// A property's type: one scalar, or a list (a count, then that many items).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PropertyKind {
    /// One value.
    Scalar(Scalar),
    /// A count of type `count`, then that many values of type `item`.
    List {
        /// Type of the count (an integer type).
        count: Scalar,
        /// Type of the items.
        item: Scalar,
    },
}

impl PropertyKind {
    /// The fewest bytes one value of this property takes in a body of `encoding`.
    fn min_bytes(self, encoding: Encoding) -> usize {
        match (encoding, self) {
            // A token and a separator.
            (Encoding::Ascii, _) => 2,
            (_, PropertyKind::Scalar(s)) => s.size(),
            (_, PropertyKind::List { count, .. }) => count.size(),
        }
    }
}

/// A property of an element.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Property {
    /// Its name.
    pub name: String,
    /// Its type.
    pub kind: PropertyKind,
}

/// An element declaration: a name, how many entries, and the properties of each entry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Element {
    /// Its name (`vertex`, `face`, ...).
    pub name: String,
    /// How many entries the body holds.
    pub count: usize,
    /// Its properties, in order.
    pub properties: Vec<Property>,
}

impl Element {
    /// The index of the property called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.properties.iter().position(|p| p.name == name)
    }
}

/// The body encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Whitespace-separated text, one entry per line.
    Ascii,
    /// Binary, little-endian.
    BinaryLittleEndian,
    /// Binary, big-endian.
    BinaryBigEndian,
}

impl Encoding {
    /// The name used in the `format` line.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Ascii => "ascii",
            Encoding::BinaryLittleEndian => "binary_little_endian",
            Encoding::BinaryBigEndian => "binary_big_endian",
        }
    }
}

/// A parsed header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    /// The body encoding.
    pub encoding: Encoding,
    /// The elements, in file order.
    pub elements: Vec<Element>,
    /// `comment` lines, without the keyword.
    pub comments: Vec<String>,
    /// Byte offset of the body.
    pub body: usize,
    /// Line number (1-based) of the body's first line, for ascii error messages.
    pub body_line: usize,
}

impl Header {
    /// The element called `name`.
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.name == name)
    }
}

/// Parses a PLY header at the start of `bytes`.
pub fn parse_header(bytes: &[u8]) -> Result<Header, PlyError> {
    let mut pos = 0usize;
    let mut lineno = 0usize;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut comments = Vec::new();
    // Declared names, to refuse duplicates: (0, element) and (element index + 1, property).
    let mut names: HashSet<(usize, &str)> = HashSet::new();
    // Only the first MAX_HEADER_BYTES are looked at.
    let head = bytes.get(..MAX_HEADER_BYTES).unwrap_or(bytes);
    loop {
        let rest = head.get(pos..).unwrap_or_default();
        if rest.is_empty() {
            return Err(PlyError::new(None, "the header has no end_header line"));
        }
        lineno += 1;
        let (raw, next) = match rest.iter().position(|&b| b == b'\n') {
            Some(n) => (rest.get(..n).unwrap_or_default(), pos + n + 1),
            None if head.len() < bytes.len() => {
                return Err(PlyError::new(
                    None,
                    format!("no end_header in the first {MAX_HEADER_BYTES} bytes"),
                ))
            }
            None => (rest, bytes.len()),
        };
        pos = next;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let line = std::str::from_utf8(raw)
            .map_err(|_| PlyError::new(Some(lineno), "the header is not text"))?;
        let err = |m: String| PlyError::new(Some(lineno), m);
        if lineno == 1 {
            if line.trim_end() != "ply" {
                return Err(err("not a PLY file (the first line is not `ply`)".into()));
            }
            continue;
        }
        let mut t = line.split_ascii_whitespace();
        match t.next() {
            None => {}
            Some("comment") => {
                let text = line
                    .trim_start()
                    .strip_prefix("comment")
                    .unwrap_or_default();
                comments.push(text.trim().to_string());
            }
            Some("obj_info") => {}
            Some("format") => {
                if encoding.is_some() {
                    return Err(err("a second format line".into()));
                }
                encoding = Some(match t.next() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::BinaryLittleEndian,
                    Some("binary_big_endian") => Encoding::BinaryBigEndian,
                    Some(other) => return Err(err(format!("unknown format `{other}`"))),
                    None => return Err(err("the format line names no format".into())),
                });
            }
            Some("element") => {
                let name = t
                    .next()
                    .ok_or_else(|| err("element without a name".into()))?;
                let count = t
                    .next()
                    .ok_or_else(|| err(format!("element {name} has no count")))?;
                let count = count
                    .parse::<usize>()
                    .map_err(|_| err(format!("element {name} has an invalid count `{count}`")))?;
                if !names.insert((0, name)) {
                    return Err(err(format!("element {name} is declared twice")));
                }
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            Some("property") => {
                let owner = elements.len();
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err("property before any element".into()))?;
                let ty = t
                    .next()
                    .ok_or_else(|| err("property without a type".into()))?;
                let kind = if ty == "list" {
                    let count = t.next().unwrap_or_default();
                    let count = Scalar::from_name(count)
                        .ok_or_else(|| err(format!("unknown list count type `{count}`")))?;
                    if !count.is_integer() {
                        return Err(err(format!(
                            "list count type {} is not an integer type",
                            count.name()
                        )));
                    }
                    let item = t.next().unwrap_or_default();
                    let item = Scalar::from_name(item)
                        .ok_or_else(|| err(format!("unknown list item type `{item}`")))?;
                    PropertyKind::List { count, item }
                } else {
                    PropertyKind::Scalar(
                        Scalar::from_name(ty).ok_or_else(|| err(format!("unknown type `{ty}`")))?,
                    )
                };
                let name = t
                    .next()
                    .ok_or_else(|| err("property without a name".into()))?;
                if !names.insert((owner, name)) {
                    return Err(err(format!(
                        "property {name} is declared twice in element {}",
                        el.name
                    )));
                }
                el.properties.push(Property {
                    name: name.to_string(),
                    kind,
                });
            }
            Some("end_header") => break,
            Some(other) => return Err(err(format!("unknown header keyword `{other}`"))),
        }
    }
    let encoding = encoding.ok_or_else(|| PlyError::new(None, "the header has no format line"))?;
    Ok(Header {
        encoding,
        elements,
        comments,
        body: pos,
        body_line: lineno + 1,
    })
}

/// Reads the body of a PLY file value by value, in file order.
pub struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    encoding: Encoding,
    line: usize,
}

impl<'a> Reader<'a> {
    /// A reader of the body of `bytes`, whose header is `header`.
    pub fn new(bytes: &'a [u8], header: &Header) -> Self {
        Reader {
            bytes,
            pos: header.body.min(bytes.len()),
            encoding: header.encoding,
            line: header.body_line,
        }
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// The current line, for ascii bodies.
    pub fn line(&self) -> Option<usize> {
        (self.encoding == Encoding::Ascii).then_some(self.line)
    }

    /// The line the next value starts on, for ascii bodies: whitespace before it (the end of
    /// the previous entry's line) is skipped first, so an error about the entry about to be
    /// read names that entry's line, not the one before.
    pub fn next_value_line(&mut self) -> Option<usize> {
        if self.encoding == Encoding::Ascii {
            self.skip_ascii_whitespace();
        }
        self.line()
    }

    fn skip_ascii_whitespace(&mut self) {
        while let Some(&b) = self.bytes.get(self.pos) {
            if !b.is_ascii_whitespace() {
                break;
            }
            if b == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
    }

    fn error(&self, message: impl Into<String>) -> PlyError {
        PlyError::new(self.line(), message)
    }

    /// Fails when `el.count` entries of `el` cannot possibly fit in the bytes that are left,
    /// so that a hostile count is an error before anything is allocated for it.
    pub fn check_fits(&self, el: &Element) -> Result<(), PlyError> {
        let per_entry: usize = el
            .properties
            .iter()
            .map(|p| p.kind.min_bytes(self.encoding))
            .sum();
        // The last ascii token needs no separator after it.
        let slack = usize::from(self.encoding == Encoding::Ascii);
        let fits = el
            .count
            .checked_mul(per_entry)
            .is_some_and(|need| need <= self.remaining().saturating_add(slack));
        if fits {
            Ok(())
        } else {
            Err(self.error(format!(
                "element {} claims {} entries, more than the {} bytes left can hold",
                el.name,
                el.count,
                self.remaining()
            )))
        }
    }

    /// Reads one scalar of type `ty`. Float values of type `float` come back rounded to
    /// `f32`; integer values are checked against their type's range.
    pub fn scalar(&mut self, ty: Scalar) -> Result<f64, PlyError> {
        match self.encoding {
            Encoding::Ascii => self.ascii_scalar(ty),
            Encoding::BinaryLittleEndian => self.binary_scalar(ty, false),
            Encoding::BinaryBigEndian => self.binary_scalar(ty, true),
        }
    }

    fn ascii_scalar(&mut self, ty: Scalar) -> Result<f64, PlyError> {
        self.skip_ascii_whitespace();
        let start = self.pos;
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        let token = self.bytes.get(start..self.pos).unwrap_or_default();
        if token.is_empty() {
            return Err(self.error("unexpected end of data"));
        }
        let token = std::str::from_utf8(token)
            .map_err(|_| self.error("a value that is not text in an ascii body"))?;
        match ty.int_range() {
            Some((lo, hi)) => {
                let v: i64 = token.parse().map_err(|_| {
                    self.error(format!(
                        "`{token}` is not an integer ({} expected)",
                        ty.name()
                    ))
                })?;
                if v < lo || v > hi {
                    return Err(self.error(format!("{v} is out of range for {}", ty.name())));
                }
                Ok(v as f64)
            }
            None => {
                let v: f64 = token
                    .parse()
                    .map_err(|_| self.error(format!("`{token}` is not a number")))?;
                Ok(if ty == Scalar::F32 {
                    f64::from(v as f32)
                } else {
                    v
                })
            }
        }
    }

    fn binary_scalar(&mut self, ty: Scalar, big_endian: bool) -> Result<f64, PlyError> {
        let n = ty.size();
        let raw = self
            .bytes
            .get(self.pos..self.pos.saturating_add(n))
            .ok_or_else(|| self.error("unexpected end of data"))?;
        self.pos += n;
        let mut b = [0u8; 8];
        for (dst, src) in b.iter_mut().zip(raw) {
            *dst = *src;
        }
        if big_endian {
            if let Some(head) = b.get_mut(..n) {
                head.reverse();
            }
        }
        let [b0, b1, b2, b3, ..] = b;
        Ok(match ty {
            Scalar::I8 => f64::from(b0 as i8),
            Scalar::U8 => f64::from(b0),
            Scalar::I16 => f64::from(i16::from_le_bytes([b0, b1])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b0, b1])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::F64 => f64::from_le_bytes(b),
        })
    }

    /// Reads a list's length (of type `count`), checked against the bytes left for that many
    /// items of type `item`.
    pub fn list_len(&mut self, count: Scalar, item: Scalar) -> Result<usize, PlyError> {
        let n = self.scalar(count)?;
        if n.is_nan() || n < 0.0 || n.fract() != 0.0 {
            return Err(self.error(format!("invalid list length {n}")));
        }
        // Exact: every integer type fits in an f64 and in a usize on 32- and 64-bit targets.
        let n = n as usize;
        let min = PropertyKind::Scalar(item).min_bytes(self.encoding);
        let slack = usize::from(self.encoding == Encoding::Ascii);
        if n.saturating_mul(min) > self.remaining().saturating_add(slack) {
            return Err(self.error(format!("a list of {n} items runs past the end of the file")));
        }
        Ok(n)
    }

    /// Reads a list of `count` type `count` and items of type `item`, appending the items to
    /// `out`; returns how many there were.
    pub fn list(
        &mut self,
        count: Scalar,
        item: Scalar,
        out: &mut Vec<f64>,
    ) -> Result<usize, PlyError> {
        let n = self.list_len(count, item)?;
        out.reserve(n);
        for _ in 0..n {
            out.push(self.scalar(item)?);
        }
        Ok(n)
    }

    /// Skips one value of a property.
    pub fn skip(&mut self, kind: PropertyKind) -> Result<(), PlyError> {
        match kind {
            PropertyKind::Scalar(s) => self.skip_scalar(s),
            PropertyKind::List { count, item } => {
                let n = self.list_len(count, item)?;
                for _ in 0..n {
                    self.skip_scalar(item)?;
                }
                Ok(())
            }
        }
    }

    fn skip_scalar(&mut self, ty: Scalar) -> Result<(), PlyError> {
        if self.encoding == Encoding::Ascii {
            self.scalar(ty).map(|_| ())
        } else if self.remaining() >= ty.size() {
            self.pos += ty.size();
            Ok(())
        } else {
            Err(self.error("unexpected end of data"))
        }
    }

    /// Skips every entry of an element.
    pub fn skip_element(&mut self, el: &Element) -> Result<(), PlyError> {
        if el.properties.is_empty() {
            return Ok(());
        }
        self.check_fits(el)?;
        for _ in 0..el.count {
            for p in &el.properties {
                self.skip(p.kind)?;
            }
        }
        Ok(())
    }
}

/// Writes a PLY file: the header first ([`Writer::new`]), then the values of each entry of
/// each element in order ([`Writer::scalar`], [`Writer::list`]), closing each entry with
/// [`Writer::end_entry`]. The writer does not check that the values match the declared
/// properties; that is the caller's part.
pub struct Writer {
    out: Vec<u8>,
    encoding: Encoding,
    line_start: bool,
}

impl Writer {
    /// A writer whose header declares `elements` (with their counts) and `comments`.
    /// Names and comments should hold no line breaks; any that do are replaced by spaces.
    pub fn new(encoding: Encoding, elements: &[Element], comments: &[&str]) -> Self {
        let clean = |s: &str| s.replace(['\r', '\n'], " ");
        let mut h = String::new();
        let _ = writeln!(h, "ply\nformat {} 1.0", encoding.name());
        for c in comments {
            let _ = writeln!(h, "comment {}", clean(c));
        }
        for el in elements {
            let _ = writeln!(h, "element {} {}", clean(&el.name), el.count);
            for p in &el.properties {
                let _ = match p.kind {
                    PropertyKind::Scalar(s) => {
                        writeln!(h, "property {} {}", s.name(), clean(&p.name))
                    }
                    PropertyKind::List { count, item } => writeln!(
                        h,
                        "property list {} {} {}",
                        count.name(),
                        item.name(),
                        clean(&p.name)
                    ),
                };
            }
        }
        h.push_str("end_header\n");
        Writer {
            out: h.into_bytes(),
            encoding,
            line_start: true,
        }
    }

    /// Appends one scalar. `v` is converted to `ty` (integers saturate, so out-of-range
    /// values are clamped); ascii floats are written so that they read back exactly.
    pub fn scalar(&mut self, ty: Scalar, v: f64) {
        let big = match self.encoding {
            Encoding::Ascii => {
                if !self.line_start {
                    self.out.push(b' ');
                }
                self.line_start = false;
                let mut s = String::new();
                let _ = match ty {
                    Scalar::F32 => write!(s, "{}", v as f32),
                    Scalar::F64 => write!(s, "{v}"),
                    _ => write!(s, "{}", v as i64),
                };
                self.out.extend_from_slice(s.as_bytes());
                return;
            }
            Encoding::BinaryLittleEndian => false,
            Encoding::BinaryBigEndian => true,
        };
        macro_rules! put {
            ($x:expr) => {{
                let x = $x;
                if big {
                    self.out.extend_from_slice(&x.to_be_bytes())
                } else {
                    self.out.extend_from_slice(&x.to_le_bytes())
                }
            }};
        }
        match ty {
            Scalar::I8 => put!(v as i8),
            Scalar::U8 => put!(v as u8),
            Scalar::I16 => put!(v as i16),
            Scalar::U16 => put!(v as u16),
            Scalar::I32 => put!(v as i32),
            Scalar::U32 => put!(v as u32),
            Scalar::F32 => put!(v as f32),
            Scalar::F64 => put!(v),
        }
    }

    /// Appends a list: its length as type `count`, then the items as type `item`.
    pub fn list(&mut self, count: Scalar, item: Scalar, values: &[f64]) {
        self.scalar(count, values.len() as f64);
        for &v in values {
            self.scalar(item, v);
        }
    }

    /// Ends one entry (a line break in ascii).
    pub fn end_entry(&mut self) {
        if self.encoding == Encoding::Ascii {
            self.out.push(b'\n');
            self.line_start = true;
        }
    }

    /// The bytes written.
    pub fn finish(self) -> Vec<u8> {
        self.out
    }
}

/// Reads a PLY mesh: the `vertex` element's `x y z` and the `face` element's vertex index
/// lists (`vertex_indices` or `vertex_index`), polygons triangulated as fans.
pub(super) fn parse_ply(
    name: &str,
    data: &[u8],
    report: &mut LoadReport,
) -> Result<Mesh, MeshError> {
    let ply_err = |e: PlyError| MeshError::Parse {
        path: name.to_string(),
        line: e.line,
        message: e.message,
    };
    let header = parse_header(data).map_err(ply_err)?;
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
    let mut r = Reader::new(data, &header);
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
                    let line = r.next_value_line();
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
                    let line = r.next_value_line();
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

/// Test helpers shared by the readers' tests: a xorshift generator and an input mutator.
#[cfg(test)]
pub(crate) mod fuzz {
    /// How many inputs each fuzz test tries: 4000, or `OCTOPROXY_FUZZ_ITERATIONS`.
    pub(crate) fn iterations() -> usize {
        std::env::var("OCTOPROXY_FUZZ_ITERATIONS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(4000)
    }

    /// A xorshift64 random generator.
    pub(crate) struct Rng(u64);

    impl Rng {
        /// A generator from a seed.
        pub(crate) fn new(seed: u64) -> Self {
            Rng(seed | 1)
        }

        /// The next random number.
        pub(crate) fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        /// A random number below `n` (0 when `n` is 0).
        pub(crate) fn below(&mut self, n: usize) -> usize {
            (self.next() % n.max(1) as u64) as usize
        }

        /// `seed` changed a little, at random: truncated, bits flipped, bytes replaced,
        /// tokens inserted, chunks duplicated, words overwritten, or all random bytes.
        pub(crate) fn mutate(&mut self, seed: &[u8]) -> Vec<u8> {
            let mut b = seed.to_vec();
            for _ in 0..1 + self.below(4) {
                match self.below(8) {
                    0 => {
                        let n = self.below(b.len() + 1);
                        b.truncate(n);
                    }
                    1 | 2 if !b.is_empty() => {
                        let i = self.below(b.len());
                        b[i] ^= 1 << self.below(8);
                    }
                    3 if !b.is_empty() => {
                        const BYTES: &[u8] = b" \n-.0123456789eE/#nanif\r\xff\x00";
                        let i = self.below(b.len());
                        b[i] = BYTES[self.below(BYTES.len())];
                    }
                    4 => {
                        const TOKENS: [&[u8]; 9] = [
                            b"4294967295",
                            b"-1",
                            b"1e999",
                            b"nan",
                            b" list ",
                            b"\nf 1 2 99\n",
                            b"99999999999999999999",
                            b"0",
                            b"\nend_header\n",
                        ];
                        let i = self.below(b.len() + 1);
                        let t = TOKENS[self.below(TOKENS.len())];
                        b.splice(i..i, t.iter().copied());
                    }
                    5 if !b.is_empty() => {
                        let i = self.below(b.len());
                        let j = (i + self.below(64)).min(b.len());
                        let chunk = b[i..j].to_vec();
                        let k = self.below(b.len() + 1);
                        b.splice(k..k, chunk);
                    }
                    6 if b.len() >= 4 => {
                        let i = self.below(b.len() - 3);
                        let w = (self.next() as u32).to_le_bytes();
                        b[i..i + 4].copy_from_slice(&w);
                    }
                    7 => {
                        let n = self.below(300);
                        b = (0..n).map(|_| self.next() as u8).collect();
                    }
                    _ => {}
                }
            }
            b
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn el(name: &str, count: usize, props: &[(&str, PropertyKind)]) -> Element {
        Element {
            name: name.into(),
            count,
            properties: props
                .iter()
                .map(|(n, k)| Property {
                    name: (*n).into(),
                    kind: *k,
                })
                .collect(),
        }
    }

    #[test]
    fn parses_a_header_with_every_type_and_alias() {
        let mut text =
            String::from("ply\r\nformat binary_big_endian 1.0\r\ncomment hello  world\r\n");
        text.push_str("obj_info whatever\r\nelement thing 3\r\n");
        let names = [
            "char", "int8", "uchar", "uint8", "short", "int16", "ushort", "uint16", "int", "int32",
            "uint", "uint32", "float", "float32", "double", "float64",
        ];
        for (i, n) in names.iter().enumerate() {
            text.push_str(&format!("property {n} p{i}\r\n"));
        }
        text.push_str(
            "element face 0\r\nproperty list uint8 int32 vertex_indices\r\nend_header\r\nBODY",
        );
        let h = parse_header(text.as_bytes()).unwrap();
        assert_eq!(h.encoding, Encoding::BinaryBigEndian);
        assert_eq!(h.comments, vec!["hello  world".to_string()]);
        assert_eq!(h.elements.len(), 2);
        let thing = &h.elements[0];
        assert_eq!(thing.count, 3);
        let types: Vec<Scalar> = thing
            .properties
            .iter()
            .map(|p| match p.kind {
                PropertyKind::Scalar(s) => s,
                PropertyKind::List { .. } => panic!("list"),
            })
            .collect();
        use Scalar::*;
        assert_eq!(
            types,
            vec![I8, I8, U8, U8, I16, I16, U16, U16, I32, I32, U32, U32, F32, F32, F64, F64]
        );
        assert_eq!(
            h.elements[1].properties[0].kind,
            PropertyKind::List {
                count: U8,
                item: I32
            }
        );
        assert_eq!(&text.as_bytes()[h.body..], b"BODY");
        assert_eq!(h.body_line, 25);
    }

    #[test]
    fn header_errors() {
        let cases: &[(&str, &str)] = &[
            ("", "no end_header"),
            ("plx\nformat ascii 1.0\nend_header\n", "not a PLY file"),
            ("ply\nend_header\n", "no format line"),
            ("ply\nformat text 1.0\nend_header\n", "unknown format `text`"),
            ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "property before any element"),
            ("ply\nformat ascii 1.0\nelement v -1\nend_header\n", "invalid count"),
            ("ply\nformat ascii 1.0\nelement v 99999999999999999999999\nend_header\n", "invalid count"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty quad x\nend_header\n", "unknown type `quad`"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty list float int i\nend_header\n", "not an integer type"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty float x\nproperty int x\nend_header\n", "declared twice"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty float\nend_header\n", "without a name"),
            ("ply\nformat ascii 1.0\nbogus\nend_header\n", "unknown header keyword"),
            ("ply\nformat ascii 1.0\nelement v 1\n", "no end_header"),
        ];
        for (text, want) in cases {
            let e = parse_header(text.as_bytes()).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        let e = parse_header(b"ply\nformat ascii 1.0\nbogus\nend_header\n").unwrap_err();
        assert_eq!(e.line, Some(3));
    }

    /// Writes two elements (scalars of every type, and lists) and reads them back.
    fn round_trip(encoding: Encoding) {
        use Scalar::*;
        let types = [I8, U8, I16, U16, I32, U32, F32, F64];
        let props: Vec<(String, PropertyKind)> = types
            .iter()
            .map(|t| (format!("p_{}", t.name()), PropertyKind::Scalar(*t)))
            .collect();
        let props: Vec<(&str, PropertyKind)> =
            props.iter().map(|(n, k)| (n.as_str(), *k)).collect();
        let list = PropertyKind::List {
            count: U8,
            item: U32,
        };
        let rows: Vec<[f64; 8]> = vec![
            [
                -128.0,
                255.0,
                -32768.0,
                65535.0,
                -2147483648.0,
                4294967295.0,
                0.1f32 as f64,
                0.1,
            ],
            [
                127.0,
                0.0,
                32767.0,
                0.0,
                2147483647.0,
                0.0,
                -1e-30f32 as f64,
                f64::MAX,
            ],
            [0.0, 1.0, -1.0, 1.0, -1.0, 1.0, f64::INFINITY, -0.0],
        ];
        let lists: Vec<Vec<f64>> = vec![vec![0.0, 1.0, 2.0], vec![], vec![4294967295.0; 5]];
        let elements = [
            el("thing", rows.len(), &props),
            el("face", lists.len(), &[("vertex_indices", list)]),
        ];
        let mut w = Writer::new(encoding, &elements, &["made by a test"]);
        for r in &rows {
            for (t, v) in types.iter().zip(r) {
                w.scalar(*t, *v);
            }
            w.end_entry();
        }
        for l in &lists {
            w.list(U8, U32, l);
            w.end_entry();
        }
        let bytes = w.finish();
        let h = parse_header(&bytes).unwrap();
        assert_eq!(h.encoding, encoding);
        assert_eq!(h.elements, elements);
        let mut r = Reader::new(&bytes, &h);
        r.check_fits(&h.elements[0]).unwrap();
        for row in &rows {
            for (t, v) in types.iter().zip(row) {
                let got = r.scalar(*t).unwrap();
                assert_eq!(got.to_bits(), v.to_bits(), "{encoding:?} {t:?}");
            }
        }
        for l in &lists {
            let mut got = Vec::new();
            assert_eq!(r.list(U8, U32, &mut got).unwrap(), l.len());
            assert_eq!(&got, l);
        }
        // Only the last line break is left.
        assert_eq!(r.remaining(), usize::from(encoding == Encoding::Ascii));
        assert!(r.scalar(U8).is_err());
    }

    #[test]
    fn round_trips_ascii() {
        round_trip(Encoding::Ascii);
    }

    #[test]
    fn round_trips_binary_little_endian() {
        round_trip(Encoding::BinaryLittleEndian);
    }

    #[test]
    fn round_trips_binary_big_endian() {
        round_trip(Encoding::BinaryBigEndian);
    }

    #[test]
    fn big_endian_bytes_by_hand() {
        let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement v 1\nproperty short a\nproperty float b\nproperty double c\nend_header\n".to_vec();
        bytes.extend_from_slice(&(-2i16).to_be_bytes());
        bytes.extend_from_slice(&1.5f32.to_be_bytes());
        bytes.extend_from_slice(&(-3.25f64).to_be_bytes());
        let h = parse_header(&bytes).unwrap();
        let mut r = Reader::new(&bytes, &h);
        assert_eq!(r.scalar(Scalar::I16).unwrap(), -2.0);
        assert_eq!(r.scalar(Scalar::F32).unwrap(), 1.5);
        assert_eq!(r.scalar(Scalar::F64).unwrap(), -3.25);
    }

    #[test]
    fn skips_elements_with_lists() {
        for enc in [
            Encoding::Ascii,
            Encoding::BinaryLittleEndian,
            Encoding::BinaryBigEndian,
        ] {
            let list = PropertyKind::List {
                count: Scalar::U16,
                item: Scalar::F64,
            };
            let elements = [
                el(
                    "junk",
                    2,
                    &[("a", PropertyKind::Scalar(Scalar::I8)), ("l", list)],
                ),
                el("v", 1, &[("x", PropertyKind::Scalar(Scalar::F32))]),
            ];
            let mut w = Writer::new(enc, &elements, &[]);
            w.scalar(Scalar::I8, -5.0);
            w.list(Scalar::U16, Scalar::F64, &[1.0, 2.0, 3.0]);
            w.end_entry();
            w.scalar(Scalar::I8, 7.0);
            w.list(Scalar::U16, Scalar::F64, &[]);
            w.end_entry();
            w.scalar(Scalar::F32, 42.5);
            w.end_entry();
            let bytes = w.finish();
            let h = parse_header(&bytes).unwrap();
            let mut r = Reader::new(&bytes, &h);
            r.skip_element(&h.elements[0]).unwrap();
            assert_eq!(r.scalar(Scalar::F32).unwrap(), 42.5, "{enc:?}");
        }
    }

    #[test]
    fn hostile_counts_fail_fast() {
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nend_header\n\0\0\0\0";
        let h = parse_header(text.as_bytes()).unwrap();
        let r = Reader::new(text.as_bytes(), &h);
        let e = r.check_fits(&h.elements[0]).unwrap_err().to_string();
        assert!(e.contains("claims 4000000000 entries"), "{e}");
        let huge = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty list uint uint x\nend_header\n1 2\n",
            usize::MAX
        );
        let h = parse_header(huge.as_bytes()).unwrap();
        let r = Reader::new(huge.as_bytes(), &h);
        assert!(r.check_fits(&h.elements[0]).is_err());
        // A list length far beyond the data.
        let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement f 1\nproperty list uint int i\nend_header\n".to_vec();
        bytes.extend_from_slice(&u32::MAX.to_le_bytes());
        bytes.extend_from_slice(&[0; 12]);
        let h = parse_header(&bytes).unwrap();
        let mut r = Reader::new(&bytes, &h);
        let e = r
            .list_len(Scalar::U32, Scalar::I32)
            .unwrap_err()
            .to_string();
        assert!(e.contains("runs past the end"), "{e}");
        // Property-less elements with absurd counts are skipped at once.
        let text = format!(
            "ply\nformat binary_little_endian 1.0\nelement nothing {}\nend_header\n",
            usize::MAX
        );
        let h = parse_header(text.as_bytes()).unwrap();
        Reader::new(text.as_bytes(), &h)
            .skip_element(&h.elements[0])
            .unwrap();
    }

    #[test]
    fn ascii_value_errors_name_the_line() {
        let text = "ply\nformat ascii 1.0\nelement v 2\nproperty uchar a\nproperty float b\nend_header\n1 2.5\n300 1\n";
        let h = parse_header(text.as_bytes()).unwrap();
        let mut r = Reader::new(text.as_bytes(), &h);
        assert_eq!(r.scalar(Scalar::U8).unwrap(), 1.0);
        assert_eq!(r.scalar(Scalar::F32).unwrap(), 2.5);
        let e = r.scalar(Scalar::U8).unwrap_err();
        assert_eq!(e.line, Some(8));
        assert!(
            e.to_string().contains("300 is out of range for uchar"),
            "{e}"
        );
        let text = "ply\nformat ascii 1.0\nelement v 1\nproperty int a\nend_header\n1.5\n";
        let h = parse_header(text.as_bytes()).unwrap();
        let e = Reader::new(text.as_bytes(), &h)
            .scalar(Scalar::I32)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 6") && e.contains("not an integer"), "{e}");
    }

    #[test]
    fn a_header_with_many_properties_parses_quickly() {
        let mut text = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 1\n");
        for i in 0..40_000 {
            text.push_str(&format!("property uchar p{i}\n"));
        }
        text.push_str("end_header\n");
        let t = std::time::Instant::now();
        let h = parse_header(text.as_bytes()).unwrap();
        assert_eq!(h.elements[0].properties.len(), 40_000);
        assert!(t.elapsed().as_secs_f64() < 1.0);
        let dup = text.replace("property uchar p39999\n", "property uchar p3\n");
        let e = parse_header(dup.as_bytes()).unwrap_err();
        assert_eq!(e.line, Some(40_003));
    }

    #[test]
    fn ascii_floats_read_as_their_type() {
        let text = "ply\nformat ascii 1.0\nelement v 1\nproperty float a\nproperty double b\nend_header\n0.1 0.1\n";
        let h = parse_header(text.as_bytes()).unwrap();
        let mut r = Reader::new(text.as_bytes(), &h);
        assert_eq!(r.scalar(Scalar::F32).unwrap(), f64::from(0.1f32));
        assert_eq!(r.scalar(Scalar::F64).unwrap(), 0.1);
    }
}
