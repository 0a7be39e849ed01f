//! Gzip detection and capped decompression, for every reader: a gzipped file is recognised
//! by its magic bytes, whatever its name.

use std::borrow::Cow;
use std::io::Read;

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
