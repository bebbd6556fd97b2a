//! Bytes kept deflated in memory until they are needed: what a bake holds for a part that
//! may never draw (the texel volumes, 92 % air, deflate to about a thirteenth).

use std::io::{Read, Write};

/// A byte string held deflated (DEFLATE at its fast level), with its length.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedBytes {
    deflated: Vec<u8>,
    len: usize,
}

impl PackedBytes {
    /// `bytes` deflated.
    pub fn pack(bytes: &[u8]) -> Self {
        let mut e = flate2::write::DeflateEncoder::new(
            Vec::with_capacity(bytes.len() / 8),
            flate2::Compression::fast(),
        );
        // Writing into a Vec cannot fail.
        let deflated = e
            .write_all(bytes)
            .and_then(|()| e.finish())
            .unwrap_or_default();
        let mut deflated = deflated;
        deflated.shrink_to_fit();
        Self {
            deflated,
            len: bytes.len(),
        }
    }

    /// The bytes as they were packed.
    pub fn unpack(&self) -> std::io::Result<Vec<u8>> {
        let mut out = Vec::with_capacity(self.len);
        flate2::read::DeflateDecoder::new(&self.deflated[..]).read_to_end(&mut out)?;
        if out.len() != self.len {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "packed bytes inflated to {} bytes, not {}",
                    out.len(),
                    self.len
                ),
            ));
        }
        Ok(out)
    }

    /// Length of the bytes as they were packed.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes held.
    pub fn held_bytes(&self) -> u64 {
        self.deflated.capacity() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_bytes_unpack_to_themselves_and_hold_less_when_they_repeat() {
        let mut bytes = vec![0u8; 100_000];
        for (i, b) in bytes.iter_mut().enumerate().step_by(37) {
            *b = (i % 251) as u8;
        }
        let p = PackedBytes::pack(&bytes);
        assert_eq!(p.len(), bytes.len());
        assert!(
            p.held_bytes() < bytes.len() as u64 / 4,
            "{}",
            p.held_bytes()
        );
        assert_eq!(p.unpack().unwrap(), bytes);
        let empty = PackedBytes::pack(&[]);
        assert!(empty.is_empty());
        assert_eq!(empty.unpack().unwrap(), Vec::<u8>::new());
    }

    #[test]
    fn packed_bytes_that_inflate_to_another_length_are_refused() {
        let mut p = PackedBytes::pack(&[7u8; 1000]);
        p.len = 999;
        assert!(p.unpack().is_err());
    }
}
