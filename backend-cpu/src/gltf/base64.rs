//! Base64 (RFC 4648, the standard alphabet) for the `data:` URIs of embedded glTF buffers: a
//! strict decoder (padding optional, nothing else allowed) and the encoder tests use.

const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

fn sextet(c: u8) -> Option<u32> {
    match c {
        b'A'..=b'Z' => Some((c - b'A') as u32),
        b'a'..=b'z' => Some((c - b'a') as u32 + 26),
        b'0'..=b'9' => Some((c - b'0') as u32 + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    }
}

/// Decodes base64 text; the error says where it is malformed.
pub fn decode_base64(text: &[u8]) -> Result<Vec<u8>, String> {
    let body = match text {
        [rest @ .., b'=', b'='] => rest,
        [rest @ .., b'='] => rest,
        _ => text,
    };
    if (text.len() != body.len() && !text.len().is_multiple_of(4)) || body.len() % 4 == 1 {
        return Err(format!(
            "base64 data of {} characters has a bad length",
            text.len()
        ));
    }
    let mut out = Vec::with_capacity(body.len() / 4 * 3 + 2);
    for (k, chunk) in body.chunks(4).enumerate() {
        let mut acc = 0u32;
        for (j, &c) in chunk.iter().enumerate() {
            let v = sextet(c).ok_or_else(|| {
                format!(
                    "base64 data has a bad character `{}` at position {}",
                    c.escape_ascii(),
                    k * 4 + j
                )
            })?;
            acc |= v << (18 - 6 * j);
        }
        let bytes = acc.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    Ok(out)
}

/// Encodes bytes as base64 text with padding.
pub fn encode_base64(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let mut b = [0u8; 3];
        b[..chunk.len()].copy_from_slice(chunk);
        let acc = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for j in 0..4 {
            if j <= chunk.len() {
                out.push(ALPHABET[(acc >> (18 - 6 * j) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}
