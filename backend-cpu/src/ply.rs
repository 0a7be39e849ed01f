//! A small PLY reader and writer: ascii, binary little- and big-endian, scalar and list
//! properties. It never panics on input and checks every count against the bytes left.

use std::fmt::Write as _;

/// A scalar type of a PLY property.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
    fn parse(s: &str) -> Option<Scalar> {
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

    /// The name written in headers.
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

    /// Bytes in binary files.
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Whether integer-valued.
    pub fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

/// A property's type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PropertyKind {
    /// One value.
    Scalar(Scalar),
    /// A count, then that many items.
    List {
        /// Type of the count.
        count: Scalar,
        /// Type of the items.
        item: Scalar,
    },
}

/// A property of an element.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Property {
    /// Its name.
    pub name: String,
    /// Its type.
    pub kind: PropertyKind,
}

/// An element declaration.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Element {
    /// Its name (`vertex`, `face`, ...).
    pub name: String,
    /// How many.
    pub count: usize,
    /// Its properties, in order.
    pub properties: Vec<Property>,
}

/// The body encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Whitespace-separated text.
    Ascii,
    /// Binary, little-endian.
    BinaryLittleEndian,
    /// Binary, big-endian.
    BinaryBigEndian,
}

/// A parsed header.
#[derive(Clone, Debug)]
pub struct Header {
    /// The body encoding.
    pub encoding: Encoding,
    /// The elements, in file order.
    pub elements: Vec<Element>,
    /// Byte offset of the body.
    pub body: usize,
}

/// Parses a PLY header. Errors are messages for the caller to prefix with the file name.
pub fn parse_header(bytes: &[u8]) -> Result<Header, String> {
    const END: &[u8] = b"end_header";
    let limit = bytes.len().min(1 << 20);
    let end = bytes[..limit].windows(END.len()).position(|w| w == END).ok_or("no end_header in the first MiB")?;
    let mut body = end + END.len();
    // The line ends with \n or \r\n.
    if bytes.get(body) == Some(&b'\r') {
        body += 1;
    }
    if bytes.get(body) == Some(&b'\n') {
        body += 1;
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = text.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err("not a PLY file (first line is not `ply`)".into());
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (n, line) in lines.enumerate() {
        let lineno = n + 2;
        let mut t = line.split_whitespace();
        match t.next() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                encoding = Some(match t.next() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::BinaryLittleEndian,
                    Some("binary_big_endian") => Encoding::BinaryBigEndian,
                    other => return Err(format!("line {lineno}: unknown format {other:?}")),
                });
            }
            Some("element") => {
                let name = t.next().ok_or(format!("line {lineno}: element without a name"))?;
                let count = t
                    .next()
                    .and_then(|c| c.parse::<usize>().ok())
                    .ok_or(format!("line {lineno}: element {name} has no valid count"))?;
                elements.push(Element { name: name.to_string(), count, properties: Vec::new() });
            }
            Some("property") => {
                let el = elements.last_mut().ok_or(format!("line {lineno}: property before any element"))?;
                let ty = t.next().ok_or(format!("line {lineno}: property without a type"))?;
                let kind = if ty == "list" {
                    let c = t.next().and_then(Scalar::parse).ok_or(format!("line {lineno}: bad list count type"))?;
                    let i = t.next().and_then(Scalar::parse).ok_or(format!("line {lineno}: bad list item type"))?;
                    if !c.is_integer() {
                        return Err(format!("line {lineno}: list count type must be an integer"));
                    }
                    PropertyKind::List { count: c, item: i }
                } else {
                    PropertyKind::Scalar(Scalar::parse(ty).ok_or(format!("line {lineno}: unknown type {ty:?}"))?)
                };
                let name = t.next().ok_or(format!("line {lineno}: property without a name"))?;
                el.properties.push(Property { name: name.to_string(), kind });
            }
            Some(other) => return Err(format!("line {lineno}: unknown header keyword {other:?}")),
        }
    }
    let encoding = encoding.ok_or("no format line")?;
    Ok(Header { encoding, elements, body })
}

/// Reads values from the body, element by element.
pub struct Body<'a> {
    bytes: &'a [u8],
    pos: usize,
    encoding: Encoding,
}

impl<'a> Body<'a> {
    /// A reader of the body that starts at `header.body`.
    pub fn new(bytes: &'a [u8], header: &Header) -> Self {
        Body { bytes, pos: header.body.min(bytes.len()), encoding: header.encoding }
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    /// Fails early when `count` elements of `el` cannot fit in what is left.
    pub fn check_fits(&self, el: &Element) -> Result<(), String> {
        let min_each: usize = match self.encoding {
            // Every value is at least one character plus a separator.
            Encoding::Ascii => 2 * el.properties.len().max(1),
            _ => el
                .properties
                .iter()
                .map(|p| match p.kind {
                    PropertyKind::Scalar(s) => s.size(),
                    PropertyKind::List { count, .. } => count.size(),
                })
                .sum::<usize>()
                .max(1),
        };
        if el.count.checked_mul(min_each).is_none_or(|need| need > self.remaining()) {
            return Err(format!(
                "element {} claims {} entries but the file has only {} bytes left",
                el.name,
                el.count,
                self.remaining()
            ));
        }
        Ok(())
    }

    /// Reads one scalar as `f64` (exact for every PLY type).
    pub fn scalar(&mut self, ty: Scalar) -> Result<f64, String> {
        match self.encoding {
            Encoding::Ascii => {
                let b = self.bytes;
                while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
                    self.pos += 1;
                }
                let start = self.pos;
                while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
                    self.pos += 1;
                }
                if start == self.pos {
                    return Err("unexpected end of data".into());
                }
                let tok = std::str::from_utf8(&b[start..self.pos]).map_err(|_| "non-text data in an ascii body")?;
                if ty.is_integer() {
                    let v: i64 = tok.parse().map_err(|_| format!("{tok:?} is not an integer"))?;
                    Ok(v as f64)
                } else {
                    tok.parse::<f64>().map_err(|_| format!("{tok:?} is not a number"))
                }
            }
            enc => {
                let n = ty.size();
                let raw = self.bytes.get(self.pos..self.pos + n).ok_or("unexpected end of data")?;
                self.pos += n;
                let mut buf = [0u8; 8];
                buf[..n].copy_from_slice(raw);
                if enc == Encoding::BinaryBigEndian {
                    buf[..n].reverse();
                }
                Ok(match ty {
                    Scalar::I8 => buf[0] as i8 as f64,
                    Scalar::U8 => buf[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([buf[0], buf[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([buf[0], buf[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(buf),
                })
            }
        }
    }

    /// Reads a list's count, checked against what is left.
    pub fn list_len(&mut self, count: Scalar, item: Scalar) -> Result<usize, String> {
        let n = self.scalar(count)?;
        if !(n >= 0.0) || n.fract() != 0.0 {
            return Err(format!("invalid list length {n}"));
        }
        let n = n as usize;
        let min = if self.encoding == Encoding::Ascii { 2 } else { item.size() };
        if n.saturating_mul(min) > self.remaining() {
            return Err(format!("list length {n} runs past the end of the file"));
        }
        Ok(n)
    }

    /// Skips one property's value(s).
    pub fn skip(&mut self, kind: PropertyKind) -> Result<(), String> {
        match kind {
            PropertyKind::Scalar(s) => self.scalar(s).map(|_| ()),
            PropertyKind::List { count, item } => {
                let n = self.list_len(count, item)?;
                for _ in 0..n {
                    self.scalar(item)?;
                }
                Ok(())
            }
        }
    }
}

/// Appends one scalar (given as `f64`, converted exactly back to its type) to a body.
pub fn write_scalar(out: &mut Vec<u8>, ascii: bool, ty: Scalar, v: f64) {
    if ascii {
        let mut s = String::new();
        let _ = match ty {
            Scalar::F32 => write!(s, "{}", v as f32),
            Scalar::F64 => write!(s, "{v}"),
            _ => write!(s, "{}", v as i64),
        };
        out.extend_from_slice(s.as_bytes());
        return;
    }
    match ty {
        Scalar::I8 => out.push(v as i8 as u8),
        Scalar::U8 => out.push(v as u8),
        Scalar::I16 => out.extend_from_slice(&(v as i16).to_le_bytes()),
        Scalar::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
        Scalar::I32 => out.extend_from_slice(&(v as i32).to_le_bytes()),
        Scalar::U32 => out.extend_from_slice(&(v as u32).to_le_bytes()),
        Scalar::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
        Scalar::F64 => out.extend_from_slice(&v.to_le_bytes()),
    }
}
