//! Decoding a `.canopy` file, streamed from disk ([`read`], [`read_expecting`]) or from
//! bytes ([`from_bytes`]), with every size checked before it is used (see the module docs
//! of [`crate::format`] for the order of the checks).

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use super::check::{
    check_unique_btf, check_unique_impostors, check_unique_surfels, check_unique_texels, show_len,
};
use super::*;

/// Reads and validates a `.canopy` file.
pub fn read(path: impl AsRef<Path>) -> Result<Baked, FormatError> {
    read_file(path.as_ref(), None)
}

/// Like [`read`], but fails with [`FormatError::SceneMismatch`] when the file was baked
/// for another scene hash (checked right after the header, before the data is read).
pub fn read_expecting(path: impl AsRef<Path>, scene_hash: u64) -> Result<Baked, FormatError> {
    read_file(path.as_ref(), Some(scene_hash))
}

/// Decodes and validates the bytes of a `.canopy` file.
pub fn from_bytes(bytes: &[u8]) -> Result<Baked, FormatError> {
    let mut input = Input {
        reader: bytes,
        pos: 0,
        len: bytes.len() as u64,
        path: Path::new("<memory>"),
    };
    decode(&mut input, None)
}

fn read_file(path: &Path, expected_hash: Option<u64>) -> Result<Baked, FormatError> {
    decode(&mut open(path)?, expected_hash)
}

/// The file at `path` as an [`Input`], buffered.
fn open(path: &Path) -> Result<Input<'_, BufReader<File>>, FormatError> {
    let io_error = |action| {
        move |source| FormatError::Io {
            path: path.to_owned(),
            action,
            source,
        }
    };
    let file = File::open(path).map_err(io_error("could not open"))?;
    let len = file.metadata().map_err(io_error("could not read"))?.len();
    Ok(Input {
        reader: BufReader::new(file),
        pos: 0,
        len,
        path,
    })
}

/// The most a deflated section's record data is allocated ahead of the bytes that came.
const BYTES_STEP: usize = 4 << 20;

/// A reader that knows how many bytes it has left.
struct Input<'p, R> {
    reader: R,
    pos: u64,
    len: u64,
    path: &'p Path,
}

impl<R: Read> Input<'_, R> {
    fn available(&self) -> u64 {
        self.len - self.pos
    }

    /// Fills `buf`, or fails with `Truncated` (checked before reading).
    fn fill(&mut self, buf: &mut [u8], what: &str) -> Result<(), FormatError> {
        let needed = buf.len() as u64;
        if needed > self.available() {
            return Err(FormatError::Truncated {
                what: what.to_owned(),
                needed,
                available: self.available(),
            });
        }
        self.reader
            .read_exact(buf)
            .map_err(|source| FormatError::Io {
                path: self.path.to_owned(),
                action: "could not read",
                source,
            })?;
        self.pos += needed;
        Ok(())
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FormatError> {
        let mut a = [0; N];
        self.fill(&mut a, what)?;
        Ok(a)
    }
}

pub(super) fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut a = [0; 4];
    a.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(a)
}

pub(super) fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut a = [0; 8];
    a.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(a)
}

/// One section of a file as its table gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionInfo {
    pub kind: SectionKind,
    pub packing: Packing,
    /// Bytes in the file.
    pub stored_bytes: u64,
    /// Bytes once inflated.
    pub data_bytes: u64,
}

/// The section table of a `.canopy` file, checked as [`read`] checks it (magic, version,
/// header checksum, sizes), without reading the sections.
pub fn sections(path: impl AsRef<Path>) -> Result<Vec<SectionInfo>, FormatError> {
    let header = decode_header(&mut open(path.as_ref())?, None)?;
    Ok(header
        .entries
        .iter()
        .map(|e| SectionInfo {
            kind: e.kind,
            packing: e.packing,
            stored_bytes: e.len,
            data_bytes: e.plain_len,
        })
        .collect())
}

/// The format version a `.canopy` file says it is (its first 12 bytes, the magic checked).
pub fn version_of(path: impl AsRef<Path>) -> Result<u32, FormatError> {
    let path = path.as_ref();
    let mut head = [0u8; 12];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .map_err(|source| FormatError::Io {
            path: path.to_owned(),
            action: "could not read",
            source,
        })?;
    if head[..8] != MAGIC {
        return Err(FormatError::NotCanopy {
            found: head[..8].to_vec(),
        });
    }
    Ok(u32_at(&head, 8))
}

fn decode<R: Read>(
    input: &mut Input<'_, R>,
    expected_hash: Option<u64>,
) -> Result<Baked, FormatError> {
    let header = decode_header(input, expected_hash)?;
    let mut baked = Baked::empty(header.scene_hash, header.settings);
    for (i, entry) in header.entries.iter().enumerate() {
        let name = format!("section {i} ({})", entry.kind.name());
        match entry.packing {
            Packing::Plain => decode_plain(input, entry, &name, &mut baked)?,
            Packing::Deflate => inflate::decode_deflated(input, entry, &name, &mut baked)?,
        }
    }
    check_unique_btf(&baked.btf)?;
    check_unique_texels(&baked.texels)?;
    check_unique_impostors(&baked.impostors)?;
    check_unique_surfels(&baked.surfels)?;
    Ok(baked)
}

/// What the header says, checked.
struct Header {
    scene_hash: u64,
    settings: BakeSettings,
    entries: Vec<TableEntry>,
}

fn decode_header<R: Read>(
    input: &mut Input<'_, R>,
    expected_hash: Option<u64>,
) -> Result<Header, FormatError> {
    // Magic: a short file that matches so far is truncated, anything else is not ours.
    let mut magic = [0u8; 8];
    let got = input.available().min(8) as usize;
    input.fill(&mut magic[..got], "the magic bytes")?;
    if magic[..got] != MAGIC[..got] {
        return Err(FormatError::NotCanopy {
            found: magic[..got].to_vec(),
        });
    }
    if got < MAGIC.len() {
        return Err(FormatError::Truncated {
            what: "the magic bytes".into(),
            needed: MAGIC.len() as u64,
            available: got as u64,
        });
    }
    let version_bytes = input.array::<4>("the format version")?;
    let version = u32::from_le_bytes(version_bytes);
    if !(OLDEST_VERSION..=VERSION).contains(&version) {
        return Err(FormatError::UnsupportedVersion {
            found: version,
            oldest: OLDEST_VERSION,
            supported: VERSION,
        });
    }
    let entry_bytes = if version == OLDEST_VERSION {
        SECTION_ENTRY_BYTES_V7
    } else {
        SECTION_ENTRY_BYTES
    };

    // The rest of the fixed header; `rest` starts at file offset 12 (a version-8 or older
    // file has no surfel budget: it reads as 0).
    let mut rest = [0u8; FIXED_HEADER_BYTES - 12];
    let fixed_len = if version >= 9 {
        FIXED_HEADER_BYTES
    } else {
        FIXED_HEADER_BYTES_V8
    };
    input.fill(&mut rest[..fixed_len - 12], "the header")?;
    let rest = &rest[..fixed_len - 12];
    let section_count = u32_at(rest, 0);
    if section_count > MAX_SECTIONS {
        return Err(FormatError::AbsurdSize {
            field: "section count".into(),
            value: section_count.into(),
            limit: MAX_SECTIONS.into(),
        });
    }
    let table_len = section_count as usize * entry_bytes;
    if table_len as u64 + 4 > input.available() {
        return Err(FormatError::Truncated {
            what: format!("the section table ({section_count} entries) and header checksum"),
            needed: table_len as u64 + 4,
            available: input.available(),
        });
    }
    let mut table = vec![0u8; table_len];
    input.fill(&mut table, "the section table")?;
    let stored = u32::from_le_bytes(input.array::<4>("the header checksum")?);
    let mut hasher = crc32fast::Hasher::new();
    hasher.update(&magic);
    hasher.update(&version_bytes);
    hasher.update(rest);
    hasher.update(&table);
    let computed = hasher.finalize();
    if stored != computed {
        return Err(FormatError::ChecksumMismatch {
            section: "header".into(),
            stored,
            computed,
        });
    }

    // The header is intact: check what it says.
    let header_len = input.pos;
    let file_size = u64_at(rest, 4);
    if file_size > input.len {
        return Err(FormatError::Truncated {
            what: "the whole file (size from its header)".into(),
            needed: file_size,
            available: input.len,
        });
    }
    if file_size < input.len {
        return Err(FormatError::MalformedContent {
            section: "the file".into(),
            reason: format!(
                "{} unexpected bytes follow the declared end of the file ({file_size} bytes)",
                input.len - file_size
            ),
        });
    }
    let scene_hash = u64_at(rest, 12);
    if let Some(expected) = expected_hash
        && expected != scene_hash
    {
        return Err(FormatError::SceneMismatch {
            found: scene_hash,
            expected,
        });
    }
    let settings = BakeSettings::from_header_words(std::array::from_fn(|i| {
        let at = 20 + 4 * i;
        if at + 4 <= rest.len() {
            u32_at(rest, at)
        } else {
            0
        }
    }))?;
    settings.validate()?;

    let mut entries = Vec::with_capacity(section_count as usize);
    let mut total: u64 = 0;
    for (i, entry) in table.chunks_exact(entry_bytes).enumerate() {
        let entry = TableEntry::parse(i, entry)?;
        // At most 4096 * 2^30: cannot overflow.
        total += entry.len;
        entries.push(entry);
    }
    if total != file_size - header_len {
        return Err(FormatError::MalformedContent {
            section: "the section table".into(),
            reason: format!(
                "the sections hold {total} bytes but the file has {} bytes after the header",
                file_size - header_len
            ),
        });
    }

    Ok(Header {
        scene_hash,
        settings,
        entries,
    })
}

/// One entry of the section table, checked on its own.
struct TableEntry {
    kind: SectionKind,
    crc: u32,
    /// Bytes as stored.
    len: u64,
    packing: Packing,
    /// Bytes once inflated (`len` for a plain section).
    plain_len: u64,
}

impl TableEntry {
    /// Entry `i` of the table: 16 bytes in a version-7 file (no packing), 28 in version 8.
    fn parse(i: usize, entry: &[u8]) -> Result<TableEntry, FormatError> {
        let tag = u32_at(entry, 0);
        let crc = u32_at(entry, 4);
        let len = u64_at(entry, 8);
        let Some(kind) = SectionKind::from_u32(tag) else {
            return Err(FormatError::MalformedContent {
                section: format!("section {i}"),
                reason: format!(
                    "unknown section kind {tag} (known: 1 = btf, 2 = vcm, 3 = texel, 4 = impostor, 5 = surfel)"
                ),
            });
        };
        let malformed = |reason: String| FormatError::MalformedContent {
            section: format!("section {i} ({})", kind.name()),
            reason,
        };
        let (packing, plain_len) = if entry.len() == SECTION_ENTRY_BYTES {
            let tag = u32_at(entry, 16);
            let packing = Packing::from_u32(tag).ok_or_else(|| {
                malformed(format!("packing {tag} is not 0 (as it is) or 1 (deflate)"))
            })?;
            (packing, u64_at(entry, 20))
        } else {
            (Packing::Plain, len)
        };
        for (what, value) in [("length", len), ("inflated length", plain_len)] {
            if value > MAX_SECTION_BYTES {
                return Err(FormatError::AbsurdSize {
                    field: format!("the {what} of section {i} ({})", kind.name()),
                    value,
                    limit: MAX_SECTION_BYTES,
                });
            }
        }
        if plain_len < SECTION_PREFIX_BYTES {
            return Err(malformed(format!(
                "its length is {plain_len}, too short for a record count"
            )));
        }
        if packing == Packing::Plain && plain_len != len {
            return Err(malformed(format!(
                "it is stored as it is in {len} bytes but its inflated length says {plain_len}"
            )));
        }
        if len == 0 {
            return Err(malformed("its deflated payload is empty".into()));
        }
        Ok(TableEntry {
            kind,
            crc,
            len,
            packing,
            plain_len,
        })
    }
}

impl TableEntry {
    /// The section's checksum against the one `computed` over its stored bytes.
    fn check_crc(&self, name: &str, computed: u32) -> Result<(), FormatError> {
        if self.crc != computed {
            return Err(FormatError::ChecksumMismatch {
                section: name.to_owned(),
                stored: self.crc,
                computed,
            });
        }
        Ok(())
    }
}

/// Decodes the records of a section into `baked`; the section must end with the last one.
fn decode_records<R: Read>(
    section: &mut Section<'_, '_, R>,
    kind: SectionKind,
    baked: &mut Baked,
) -> Result<(), FormatError> {
    match kind {
        SectionKind::Btf => decode_btf(section, &mut baked.btf),
        SectionKind::Vcm => decode_vcm(section, &mut baked.vcm),
        SectionKind::Texel => decode_texels(section, &mut baked.texels),
        SectionKind::Impostor => decode_impostors(section, &mut baked.impostors),
        SectionKind::Surfel => decode_surfels(section, &mut baked.surfels),
    }?;
    if section.remaining != 0 {
        return Err(section.malformed(format!(
            "{} bytes are left after the last record",
            section.remaining
        )));
    }
    Ok(())
}

/// A section stored as it is: its records are read from the file, and hashed as they are.
fn decode_plain<R: Read>(
    input: &mut Input<'_, R>,
    entry: &TableEntry,
    name: &str,
    baked: &mut Baked,
) -> Result<(), FormatError> {
    let mut section = Section {
        input,
        remaining: entry.len,
        hasher: crc32fast::Hasher::new(),
        name,
        sizes_backed: true,
    };
    let result = decode_records(&mut section, entry.kind, baked);
    match result {
        Ok(()) => {}
        // The content does not decode: unless it is corrupt, report that.
        Err(FormatError::MalformedContent { .. }) => section.drain()?,
        Err(e) => return Err(e),
    }
    entry.check_crc(name, section.hasher.finalize())?;
    result
}

/// The payload of one section: reads never go past its end, and everything read is hashed.
struct Section<'a, 'p, R> {
    input: &'a mut Input<'p, R>,
    remaining: u64,
    hasher: crc32fast::Hasher,
    name: &'a str,
    /// Whether `remaining` counts bytes the file holds (a plain section) rather than bytes
    /// an entry promises (a deflated one): only then is a record's data allocated whole
    /// before it is read.
    sizes_backed: bool,
}

impl<R: Read> Section<'_, '_, R> {
    fn malformed(&self, reason: String) -> FormatError {
        FormatError::MalformedContent {
            section: self.name.to_owned(),
            reason,
        }
    }

    fn fill(&mut self, buf: &mut [u8], what: &str) -> Result<(), FormatError> {
        let needed = buf.len() as u64;
        if needed > self.remaining {
            return Err(self.malformed(format!(
                "{what} needs {needed} bytes but the section has only {} left",
                self.remaining
            )));
        }
        self.input.fill(buf, self.name)?;
        self.hasher.update(buf);
        self.remaining -= needed;
        Ok(())
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FormatError> {
        let mut a = [0; N];
        self.fill(&mut a, what)?;
        Ok(a)
    }

    fn u32(&mut self, what: &str) -> Result<u32, FormatError> {
        self.array(what).map(u32::from_le_bytes)
    }

    fn u64(&mut self, what: &str) -> Result<u64, FormatError> {
        self.array(what).map(u64::from_le_bytes)
    }

    fn f32(&mut self, what: &str) -> Result<f32, FormatError> {
        self.array(what).map(f32::from_le_bytes)
    }

    /// The level byte, the encoding byte and the 2 reserved bytes after them: the level
    /// and the encoding's tag.
    fn level(&mut self) -> Result<(Level, u8), FormatError> {
        let [tag, encoding, r0, r1] = self.array("a level")?;
        if [r0, r1] != [0; 2] {
            return Err(self.malformed(format!(
                "the reserved bytes after a level are {:?}, not zero",
                [r0, r1]
            )));
        }
        let level = level_from_tag(tag).ok_or_else(|| {
            self.malformed(format!(
                "level {tag} is not 0 (twig), 1 (branch) or 2 (tree)"
            ))
        })?;
        Ok((level, encoding))
    }

    /// A byte vector of `len` bytes, checked against the section before allocating.
    fn bytes(&mut self, len: u64, what: &str) -> Result<Vec<u8>, FormatError> {
        if len > self.remaining {
            return Err(self.malformed(format!(
                "{what} needs {len} bytes but the section has only {} left",
                self.remaining
            )));
        }
        // len <= remaining <= MAX_SECTION_BYTES, so it fits in usize.
        let len = len as usize;
        if self.sizes_backed || len <= BYTES_STEP {
            let mut v = vec![0; len];
            self.fill(&mut v, what)?;
            return Ok(v);
        }
        // Grown as the bytes come, to exactly `len` at the end.
        let mut v = Vec::with_capacity(BYTES_STEP);
        while v.len() < len {
            let start = v.len();
            let end = len.min(start + BYTES_STEP);
            if end > v.capacity() {
                v.reserve_exact((len - v.capacity()).min(v.capacity()));
            }
            v.resize(end, 0);
            self.fill(&mut v[start..], what)?;
        }
        Ok(v)
    }

    /// Reads a record count, checked against the smallest record size.
    fn record_count(&mut self, min_record: u64) -> Result<u32, FormatError> {
        let count = self.u32("the record count")?;
        if u64::from(count) > self.remaining / min_record {
            return Err(self.malformed(format!(
                "{count} records cannot fit in the {} bytes left",
                self.remaining
            )));
        }
        Ok(count)
    }

    /// Consumes (and hashes) the rest of the section.
    fn drain(&mut self) -> Result<(), FormatError> {
        let mut buf = [0u8; 8192];
        while self.remaining > 0 {
            let n = self.remaining.min(buf.len() as u64) as usize;
            self.fill(&mut buf[..n], "the rest of the section")?;
        }
        Ok(())
    }
}

fn decode_btf<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<BtfImageSet>,
) -> Result<(), FormatError> {
    let count = s.record_count(BTF_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let species = s.u32("species")?;
        let (level, tag) = s.level()?;
        let Some(encoding) = ImageEncoding::from_tag(tag) else {
            return Err(s.malformed(format!(
                "btf record {index} (species {species}): encoding {tag} is not 0 (RGBA8) or 1 (BC7)"
            )));
        };
        let mut set = BtfImageSet {
            species,
            level,
            encoding,
            views: s.u32("views")?,
            lights: s.u32("lights")?,
            resolution: s.u32("resolution")?,
            center: [s.f32("center")?, s.f32("center")?, s.f32("center")?],
            radius: s.f32("radius")?,
            texel_size: s.f32("texel_size")?,
            direct: Vec::new(),
            ambient: Vec::new(),
        };
        let direct_len = s.u64("direct length")?;
        // The ambient length comes after the direct images; check what is known so far.
        let ambient_len = set.expected_ambient_len().unwrap_or(0);
        if let Some(reason) = set.problem(direct_len, ambient_len) {
            return Err(s.malformed(format!(
                "btf record {index} (species {}, {:?}): {reason}",
                set.species, set.level
            )));
        }
        set.direct = s.bytes(direct_len, "the direct images")?;
        let ambient_len = s.u64("ambient length")?;
        // Everything else was checked above.
        let expected = set.expected_ambient_len();
        if expected != Some(ambient_len) {
            return Err(s.malformed(format!(
                "btf record {index} (species {}, {:?}): ambient holds {ambient_len} bytes, \
                 expected {}",
                set.species,
                set.level,
                show_len(expected)
            )));
        }
        set.ambient = s.bytes(ambient_len, "the ambient images")?;
        out.push(set);
    }
    Ok(())
}

fn decode_vcm<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<VcmSet>,
) -> Result<(), FormatError> {
    let count = s.record_count(VCM_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let species = s.u32("species")?;
        let owner = s.u32("owner")?;
        let (level, tag) = s.level()?;
        let Some(encoding) = MapEncoding::from_tag(tag) else {
            return Err(s.malformed(format!(
                "vcm record {index} (owner {owner}): encoding {tag} is not 0 (R8) or 1 (BC4)"
            )));
        };
        let mut set = VcmSet {
            species,
            owner,
            level,
            encoding,
            resolution: s.u32("resolution")?,
            opacity: Vec::new(),
            mean_opacity: [0.0; 8],
        };
        for m in &mut set.mean_opacity {
            *m = s.f32("mean_opacity")?;
        }
        let opacity_len = s.u64("opacity length")?;
        if let Some(reason) = set.problem(opacity_len) {
            return Err(s.malformed(format!(
                "vcm record {index} (owner {}, {:?}): {reason}",
                set.owner, set.level
            )));
        }
        set.opacity = s.bytes(opacity_len, "the opacity maps")?;
        out.push(set);
    }
    Ok(())
}

fn decode_texels<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<TexelVolume>,
) -> Result<(), FormatError> {
    let count = s.record_count(TEXEL_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let mut t = TexelVolume {
            species: s.u32("species")?,
            lights: s.u32("lights")?,
            dims: [s.u32("dims")?, s.u32("dims")?, s.u32("dims")?],
            box_min: [s.f32("box_min")?, s.f32("box_min")?, s.f32("box_min")?],
            voxel: s.f32("voxel")?,
            voxels: Vec::new(),
        };
        let len = s.u64("voxels length")?;
        if let Some(reason) = t.problem(len) {
            return Err(s.malformed(format!(
                "texel record {index} (species {}): {reason}",
                t.species
            )));
        }
        t.voxels = s.bytes(len, "the voxels")?;
        out.push(t);
    }
    Ok(())
}

fn decode_impostors<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<Impostor>,
) -> Result<(), FormatError> {
    let count = s.record_count(IMPOSTOR_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let species = s.u32("species")?;
        let tag = s.u32("layout")?;
        let Some(layout) = OctaLayout::from_tag(tag) else {
            return Err(s.malformed(format!(
                "impostor record {index} (species {species}): layout {tag} is not 0 (full) or 1 (hemi)"
            )));
        };
        let mut imp = Impostor {
            species,
            layout,
            frames: s.u32("frames")?,
            resolution: s.u32("resolution")?,
            mip_levels: s.u32("mip_levels")?,
            center: [s.f32("center")?, s.f32("center")?, s.f32("center")?],
            radius: s.f32("radius")?,
            albedo: Vec::new(),
            normal_depth: Vec::new(),
        };
        let albedo_len = s.u64("albedo length")?;
        // The normal-depth length comes after the albedo; both must be the same.
        if let Some(reason) = imp.problem(albedo_len, albedo_len) {
            return Err(s.malformed(format!(
                "impostor record {index} (species {species}): {reason}"
            )));
        }
        imp.albedo = s.bytes(albedo_len, "the albedo atlas")?;
        let normal_len = s.u64("normal-depth length")?;
        if normal_len != albedo_len {
            return Err(s.malformed(format!(
                "impostor record {index} (species {species}): normal_depth holds {normal_len} bytes, expected {albedo_len}"
            )));
        }
        imp.normal_depth = s.bytes(normal_len, "the normal-depth atlas")?;
        out.push(imp);
    }
    Ok(())
}

fn decode_surfels<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<SurfelSet>,
) -> Result<(), FormatError> {
    const FIXED: usize = surfel::SURFEL_RECORD_FIXED_BYTES as usize;
    let count = s.record_count(FIXED as u64)?;
    for index in 0..count {
        let fixed = s.array::<FIXED>("a surfel tree record")?;
        let species = u32_at(&fixed, 0);
        let bad = |s: &Section<'_, '_, R>, reason: String| {
            s.malformed(format!(
                "surfel record {index} (species {species}): {reason}"
            ))
        };
        let (mut set, len) = SurfelSet::from_fixed(&fixed).map_err(|r| bad(s, r))?;
        let data = s.bytes(len, "the surfel tree's data")?;
        set.fill(&fixed, &data).map_err(|r| bad(s, r))?;
        out.push(set);
    }
    Ok(())
}

mod inflate;
#[cfg(test)]
mod tests;
