//! Reading a deflated section: the stored bytes are pulled from the file through a CRC as
//! the inflater asks for them, and the records are decoded from what comes out.

use std::io::Read;

use super::{Baked, FormatError, Input, Section, TableEntry, decode_records};

/// A deflated section: its stored bytes are hashed as the inflater pulls them from the file,
/// and its records read from what comes out.
pub(super) fn decode_deflated<R: Read>(
    input: &mut Input<'_, R>,
    entry: &TableEntry,
    name: &str,
    baked: &mut Baked,
) -> Result<(), FormatError> {
    let path = input.path;
    let stored = StoredBytes {
        input,
        remaining: entry.len,
        hasher: crc32fast::Hasher::new(),
        io_error: None,
    };
    let mut inflated = Input {
        reader: flate2::bufread::DeflateDecoder::new(std::io::BufReader::new(stored)),
        pos: 0,
        len: entry.plain_len,
        path,
    };
    let mut section = Section {
        input: &mut inflated,
        remaining: entry.plain_len,
        hasher: crc32fast::Hasher::new(),
        name,
        sizes_backed: false,
    };
    let mut result = decode_records(&mut section, entry.kind, baked);
    let malformed = |reason: String| FormatError::MalformedContent {
        section: name.to_owned(),
        reason,
    };
    if result.is_ok() {
        // The stream must end where the entry says.
        let mut more = [0u8; 1];
        result = match inflated.reader.read(&mut more) {
            Ok(0) => Ok(()),
            Ok(_) => Err(malformed(format!(
                "its deflated payload inflates to more than the {} bytes its table entry gives",
                entry.plain_len
            ))),
            Err(e) => Err(FormatError::Io {
                path: path.to_owned(),
                action: "could not read",
                source: e,
            }),
        };
    }
    let buffered = inflated.reader.get_mut();
    let unread = buffered.buffer().len() as u64;
    let stored = buffered.get_mut();
    if let Some(source) = stored.io_error.take() {
        return Err(FormatError::Io {
            path: path.to_owned(),
            action: "could not read",
            source,
        });
    }
    // An I/O error that is not the file's is the inflater's: the stream is not DEFLATE, or
    // ends before the bytes the entry gives.
    result = result.map_err(|e| match e {
        FormatError::Io { source, .. } => malformed(format!(
            "its deflated payload does not inflate to the {} bytes its table entry gives ({source})",
            entry.plain_len
        )),
        e => e,
    });
    let trailing = unread + stored.remaining;
    stored.drain()?;
    if result.is_ok() && trailing > 0 {
        result = Err(malformed(format!(
            "{trailing} bytes follow the end of its deflate stream"
        )));
    }
    entry.check_crc(name, stored.hasher.clone().finalize())?;
    result
}

/// The stored bytes of a deflated section, read from the file and hashed; never past the
/// section's end. A failed read of the file is kept, to be told from the inflater's errors.
struct StoredBytes<'a, 'p, R> {
    input: &'a mut Input<'p, R>,
    remaining: u64,
    hasher: crc32fast::Hasher,
    io_error: Option<std::io::Error>,
}

impl<R: Read> Read for StoredBytes<'_, '_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = (buf.len() as u64).min(self.remaining) as usize;
        if n == 0 {
            return Ok(0);
        }
        loop {
            match self.input.reader.read(&mut buf[..n]) {
                Ok(0) => {
                    // The header said the file holds these bytes: it changed while read.
                    let e = std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "the file ended early (changed while it was read?)",
                    );
                    self.io_error = Some(e);
                    return Err(std::io::Error::other("the file could not be read"));
                }
                Ok(k) => {
                    self.hasher.update(&buf[..k]);
                    self.remaining -= k as u64;
                    self.input.pos += k as u64;
                    return Ok(k);
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    self.io_error = Some(e);
                    return Err(std::io::Error::other("the file could not be read"));
                }
            }
        }
    }
}

impl<R: Read> StoredBytes<'_, '_, R> {
    /// Reads (and hashes) the rest of the stored bytes.
    fn drain(&mut self) -> Result<(), FormatError> {
        let mut buf = [0u8; 8192];
        while self.remaining > 0 {
            let n = self.remaining.min(buf.len() as u64) as usize;
            if let Err(source) = self.read_exact(&mut buf[..n]) {
                let source = self.io_error.take().unwrap_or(source);
                return Err(FormatError::Io {
                    path: self.input.path.to_owned(),
                    action: "could not read",
                    source,
                });
            }
        }
        Ok(())
    }
}
