//! Encoding a bake: the header with every checksum, then the section payloads, into bytes
//! ([`to_bytes`]) or atomically into a file ([`write_atomic`]).

use std::io::{self, Write};
use std::path::Path;

use super::plan::{PlannedSection, plan_sections};
use super::*;
use crate::atomic_file;

/// A `Write` that only computes a CRC-32 of what goes through it.
struct CrcWriter(crc32fast::Hasher);

impl Write for CrcWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.update(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn write_section_payload<W: Write + ?Sized>(
    w: &mut W,
    baked: &Baked,
    plan: &PlannedSection,
) -> io::Result<()> {
    // `pack` keeps count <= u32::MAX.
    w.write_all(&(plan.count as u32).to_le_bytes())?;
    let range = plan.first..plan.first + plan.count;
    match plan.kind {
        SectionKind::Btf => {
            for s in &baked.btf[range] {
                w.write_all(&s.species.to_le_bytes())?;
                w.write_all(&[level_tag(s.level), s.encoding.tag(), 0, 0])?;
                w.write_all(&s.views.to_le_bytes())?;
                w.write_all(&s.lights.to_le_bytes())?;
                w.write_all(&s.resolution.to_le_bytes())?;
                for c in s.center {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&s.radius.to_le_bytes())?;
                w.write_all(&s.texel_size.to_le_bytes())?;
                w.write_all(&(s.direct.len() as u64).to_le_bytes())?;
                w.write_all(&s.direct)?;
                w.write_all(&(s.ambient.len() as u64).to_le_bytes())?;
                w.write_all(&s.ambient)?;
            }
        }
        SectionKind::Vcm => {
            for s in &baked.vcm[range] {
                w.write_all(&s.species.to_le_bytes())?;
                w.write_all(&s.owner.to_le_bytes())?;
                w.write_all(&[level_tag(s.level), s.encoding.tag(), 0, 0])?;
                w.write_all(&s.resolution.to_le_bytes())?;
                for m in s.mean_opacity {
                    w.write_all(&m.to_le_bytes())?;
                }
                w.write_all(&(s.opacity.len() as u64).to_le_bytes())?;
                w.write_all(&s.opacity)?;
            }
        }
        SectionKind::Texel => {
            for t in &baked.texels[range] {
                w.write_all(&t.species.to_le_bytes())?;
                w.write_all(&t.lights.to_le_bytes())?;
                for d in t.dims {
                    w.write_all(&d.to_le_bytes())?;
                }
                for c in t.box_min {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&t.voxel.to_le_bytes())?;
                w.write_all(&(t.voxels.len() as u64).to_le_bytes())?;
                w.write_all(&t.voxels)?;
            }
        }
        SectionKind::Impostor => {
            for i in &baked.impostors[range] {
                for v in [
                    i.species,
                    i.layout.tag(),
                    i.frames,
                    i.resolution,
                    i.mip_levels,
                ] {
                    w.write_all(&v.to_le_bytes())?;
                }
                for c in i.center {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&i.radius.to_le_bytes())?;
                w.write_all(&(i.albedo.len() as u64).to_le_bytes())?;
                w.write_all(&i.albedo)?;
                w.write_all(&(i.normal_depth.len() as u64).to_le_bytes())?;
                w.write_all(&i.normal_depth)?;
            }
        }
        SectionKind::Surfel => {
            for t in &baked.surfels[range] {
                t.write(w)?;
            }
        }
    }
    Ok(())
}

/// A section's payload as the file stores it.
enum Stored {
    /// Written from the records when the file is written (nothing held).
    Plain,
    /// Deflated ahead, since the header needs its length.
    Deflated(Vec<u8>),
}

/// The section's payload as one raw DEFLATE stream (the fast level: a tenth of the time of
/// the default level for a few per cent more bytes), or `None` when that is not smaller.
fn deflate_section(baked: &Baked, plan: &PlannedSection) -> Option<Vec<u8>> {
    let capacity = usize::try_from(plan.len / 2).unwrap_or(0);
    let mut encoder = flate2::write::DeflateEncoder::new(
        Vec::with_capacity(capacity),
        flate2::Compression::fast(),
    );
    // Writing into a Vec cannot fail.
    write_section_payload(&mut encoder, baked, plan).ok()?;
    let deflated = encoder.finish().ok()?;
    ((deflated.len() as u64) < plan.len).then_some(deflated)
}

/// An encoding ready to be written: the header (checksums filled in), the section plan and
/// the sections deflated ahead.
pub(super) struct Encoding<'a> {
    baked: &'a Baked,
    header: Vec<u8>,
    plans: Vec<PlannedSection>,
    stored: Vec<Stored>,
    file_size: u64,
}

impl<'a> Encoding<'a> {
    /// Plans the sections, deflates them if asked (the sections in parallel; one that
    /// does not shrink stays plain) and computes every checksum (for a plain section one
    /// pass over the data, no copy).
    pub(super) fn new(baked: &'a Baked, section_limit: u64, packing: Packing) -> Encoding<'a> {
        use rayon::prelude::*;
        let plans = plan_sections(baked, section_limit);
        let stored: Vec<Stored> = match packing {
            Packing::Plain => plans.iter().map(|_| Stored::Plain).collect(),
            Packing::Deflate => plans
                .par_iter()
                .map(|plan| deflate_section(baked, plan).map_or(Stored::Plain, Stored::Deflated))
                .collect(),
        };
        let header_len = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * plans.len() + 4;
        let file_size = plans
            .iter()
            .zip(&stored)
            .fold(header_len as u64, |acc, (plan, stored)| {
                acc.saturating_add(match stored {
                    Stored::Plain => plan.len,
                    Stored::Deflated(bytes) => bytes.len() as u64,
                })
            });
        let mut header = Vec::with_capacity(header_len);
        header.extend_from_slice(&MAGIC);
        header.extend_from_slice(&VERSION.to_le_bytes());
        header.extend_from_slice(&(plans.len() as u32).to_le_bytes());
        header.extend_from_slice(&file_size.to_le_bytes());
        header.extend_from_slice(&baked.scene_hash.to_le_bytes());
        for v in baked.settings.header_words() {
            header.extend_from_slice(&v.to_le_bytes());
        }
        for (plan, stored) in plans.iter().zip(&stored) {
            let (crc, len, packing) = match stored {
                Stored::Plain => {
                    let mut crc = CrcWriter(crc32fast::Hasher::new());
                    // Writing into a CrcWriter cannot fail.
                    let _ = write_section_payload(&mut crc, baked, plan);
                    (crc.0.finalize(), plan.len, Packing::Plain)
                }
                Stored::Deflated(bytes) => {
                    (crc32fast::hash(bytes), bytes.len() as u64, Packing::Deflate)
                }
            };
            header.extend_from_slice(&(plan.kind as u32).to_le_bytes());
            header.extend_from_slice(&crc.to_le_bytes());
            header.extend_from_slice(&len.to_le_bytes());
            header.extend_from_slice(&(packing as u32).to_le_bytes());
            header.extend_from_slice(&plan.len.to_le_bytes());
        }
        let crc = crc32fast::hash(&header);
        header.extend_from_slice(&crc.to_le_bytes());
        Encoding {
            baked,
            header,
            plans,
            stored,
            file_size,
        }
    }

    fn write_to<W: Write + ?Sized>(&self, w: &mut W) -> io::Result<()> {
        w.write_all(&self.header)?;
        for (plan, stored) in self.plans.iter().zip(&self.stored) {
            match stored {
                Stored::Plain => write_section_payload(w, self.baked, plan)?,
                Stored::Deflated(bytes) => w.write_all(bytes)?,
            }
        }
        Ok(())
    }

    pub(super) fn into_bytes(self) -> Vec<u8> {
        let mut out = Vec::with_capacity(usize::try_from(self.file_size).unwrap_or(0));
        // Writing into a Vec cannot fail.
        let _ = self.write_to(&mut out);
        out
    }
}

/// Encodes `baked` as the bytes of a `.canopy` file with every section stored as it is
/// (the byte layout of the module docs, which tests patch). It encodes what it is given
/// without validating it (a file made from invalid data fails to read); [`write_atomic`]
/// validates first, and [`Baked::validate`] is there for callers of this function.
pub fn to_bytes(baked: &Baked) -> Vec<u8> {
    to_bytes_packed(baked, Packing::Plain)
}

/// [`to_bytes`] with the sections packed as asked ([`Packing::Deflate`]: each section that
/// shrinks deflated, as [`write_atomic`] writes them).
pub fn to_bytes_packed(baked: &Baked, packing: Packing) -> Vec<u8> {
    Encoding::new(baked, MAX_SECTION_BYTES, packing).into_bytes()
}

/// Validates `baked` and writes it to `path` atomically ([`crate::atomic_file`]): into a
/// temporary file in the same directory, synced, then renamed over `path`. On error `path`
/// is untouched (the old file, if any, stays) and the temporary file is removed. Each
/// section that shrinks deflated is stored deflated.
pub fn write_atomic(path: impl AsRef<Path>, baked: &Baked) -> Result<(), FormatError> {
    write_atomic_packed(path, baked, Packing::Deflate)
}

/// [`write_atomic`] with the sections packed as asked ([`Packing::Plain`]: all stored as
/// they are, which writes faster).
pub fn write_atomic_packed(
    path: impl AsRef<Path>,
    baked: &Baked,
    packing: Packing,
) -> Result<(), FormatError> {
    write_atomic_with_hook(path.as_ref(), baked, MAX_SECTION_BYTES, packing, |_| Ok(()))
}

/// [`write_atomic`] with the section size limit as a parameter and a hook run on the
/// complete, synced temporary file just before the rename (tests use it to simulate a
/// crash).
pub(super) fn write_atomic_with_hook(
    path: &Path,
    baked: &Baked,
    section_limit: u64,
    packing: Packing,
    before_rename: impl FnOnce(&Path) -> io::Result<()>,
) -> Result<(), FormatError> {
    baked.validate_for(section_limit)?;
    let encoding = Encoding::new(baked, section_limit, packing);
    atomic_file::write_atomic_with_hook(path, |w| encoding.write_to(w), before_rename).map_err(
        |e| FormatError::Io {
            path: e.path,
            action: e.step.action(),
            source: e.source,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::plan::{btf_record_len, plan_sections};
    use crate::format::read::{u32_at, u64_at};
    use crate::format::test_support::*;
    use crate::format::{from_bytes, read, read_expecting};
    use std::fs;

    #[test]
    fn round_trip_through_bytes() {
        let baked = sample();
        baked.validate().unwrap();
        let bytes = to_bytes(&baked);
        assert_eq!(bytes[..8], MAGIC);
        assert_eq!(u32_at(&bytes, 8), VERSION);
        assert_eq!(u64_at(&bytes, 16), bytes.len() as u64);
        assert_eq!(
            bytes.len() as u64,
            84 + 5 * 28
                + 5 * 4
                + 2 * 56
                + 2 * 56
                + 44
                + 52
                + baked.btf_bytes()
                + baked.vcm_bytes()
                + baked.texel_bytes()
                + baked.impostor_bytes()
                + baked.surfel_bytes()
        );
        assert_eq!(to_bytes(&baked), bytes, "encoding is deterministic");
        let (back, peak) = peak_during(|| from_bytes(&bytes).unwrap());
        assert!(back == baked, "decoded data differs from what was encoded");
        assert!(
            peak <= bytes.len() + SMALL_OVERHEAD,
            "decoding {} bytes held {peak} bytes",
            bytes.len()
        );
    }

    #[test]
    fn empty_bake_round_trips() {
        let baked = Baked {
            scene_hash: 7,
            settings: settings(),
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
            impostors: Vec::new(),
            surfels: Vec::new(),
        };
        let bytes = to_bytes(&baked);
        assert_eq!(bytes.len(), 84);
        assert_eq!(from_bytes(&bytes).unwrap(), baked);
    }

    #[test]
    fn records_split_over_several_sections_round_trip() {
        let baked = sample();
        // A limit that fits one BTF record per section and both VCM records in one.
        let limit = btf_record_len(&baked.btf[0]) + 4;
        let plans = plan_sections(&baked, limit);
        let kinds: Vec<_> = plans.iter().map(|p| (p.kind, p.count)).collect();
        assert_eq!(
            kinds,
            [
                (SectionKind::Btf, 1),
                (SectionKind::Btf, 1),
                (SectionKind::Vcm, 2),
                (SectionKind::Texel, 1),
                (SectionKind::Impostor, 1),
                (SectionKind::Surfel, 1)
            ]
        );
        let bytes = Encoding::new(&baked, limit, Packing::Plain).into_bytes();
        assert_eq!(section_count(&bytes), 6);
        assert!(from_bytes(&bytes).unwrap() == baked);

        // Sections of both kinds in any order decode too: put VCM first.
        let vcm_first = Baked {
            btf: Vec::new(),
            ..baked.clone()
        };
        let vcm_bytes = to_bytes(&vcm_first);
        assert_eq!(from_bytes(&vcm_bytes).unwrap(), vcm_first);
    }

    #[test]
    fn round_trip_through_a_file() {
        let dir = scratch_dir("roundtrip");
        let path = dir.join("forest.canopy");
        let baked = sample();
        write_atomic(&path, &baked).unwrap();
        assert_eq!(dir_entries(&dir), ["forest.canopy"], "no temp file left");
        let (back, peak) = peak_during(|| read(&path).unwrap());
        assert!(back == baked);
        let len = fs::metadata(&path).unwrap().len() as usize;
        assert!(
            peak <= len + SMALL_OVERHEAD,
            "reading {len} bytes held {peak}"
        );
        assert!(read_expecting(&path, baked.scene_hash).unwrap() == baked);

        // Overwriting an existing file works and leaves only the new one.
        let mut other = small();
        other.scene_hash = 99;
        write_atomic(&path, &other).unwrap();
        assert_eq!(read(&path).unwrap(), other);
        assert_eq!(dir_entries(&dir), ["forest.canopy"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_into_a_missing_directory_is_an_io_error_naming_the_path() {
        let dir = scratch_dir("nodir");
        let path = dir.join("no-such-dir").join("out.canopy");
        let err = write_atomic(&path, &small()).unwrap_err();
        match &err {
            FormatError::Io { path: p, .. } => assert_eq!(p, &path),
            other => panic!("expected an I/O error, got {other:?}"),
        }
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        assert!(dir_entries(&dir).is_empty(), "no temp file left");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_under_a_regular_file_is_an_io_error_naming_the_path() {
        let dir = scratch_dir("underfile");
        let file = dir.join("plain.txt");
        fs::write(&file, b"hello").unwrap();
        let path = file.join("out.canopy");
        let err = write_atomic(&path, &small()).unwrap_err();
        assert!(
            matches!(&err, FormatError::Io { path: p, .. } if p == &path),
            "{err:?}"
        );
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        assert_eq!(dir_entries(&dir), ["plain.txt"]);
        assert_eq!(fs::read(&file).unwrap(), b"hello");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_onto_a_directory_fails_and_cleans_up() {
        let dir = scratch_dir("ontodir");
        let target = dir.join("taken");
        fs::create_dir(&target).unwrap();
        let err = write_atomic(&target, &small()).unwrap_err();
        assert!(
            matches!(&err, FormatError::Io { path, .. } if path == &target),
            "{err:?}"
        );
        assert_eq!(dir_entries(&dir), ["taken"], "temp file removed");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn interrupted_write_leaves_the_old_file_intact() {
        let dir = scratch_dir("interrupted");
        let path = dir.join("forest.canopy");
        let old = small();
        write_atomic(&path, &old).unwrap();
        let old_bytes = fs::read(&path).unwrap();

        let new = sample();
        let mut seen_temp = None;
        let err =
            write_atomic_with_hook(&path, &new, MAX_SECTION_BYTES, Packing::Deflate, |temp| {
                // The complete new file sits next to the target, under another name.
                assert_eq!(temp.parent(), Some(dir.as_path()));
                assert_ne!(temp, path);
                assert!(from_bytes(&fs::read(temp)?).unwrap() == new);
                seen_temp = Some(temp.to_owned());
                Err(io::Error::other("simulated crash before rename"))
            })
            .unwrap_err();
        assert!(matches!(err, FormatError::Io { .. }), "{err:?}");
        let temp = seen_temp.expect("the hook ran");
        assert!(!temp.exists(), "temp file removed");
        assert_eq!(fs::read(&path).unwrap(), old_bytes, "old file untouched");
        assert_eq!(read(&path).unwrap(), old);
        assert_eq!(dir_entries(&dir), ["forest.canopy"]);

        // A crash that leaves the temp behind (no cleanup) still leaves the target intact.
        let stray = dir.join(".forest.canopy.tmp-crashed");
        fs::write(&stray, &to_bytes(&new)[..100]).unwrap();
        assert_eq!(read(&path).unwrap(), old);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_set_too_large_for_one_section_is_refused_on_write() {
        // A real case would be 258 views x 258 lights at 128² (4.4 GB in one record); the
        // same check with a small section limit.
        let dir = scratch_dir("toolarge");
        let path = dir.join("big.canopy");
        let baked = sample();
        let limit = btf_record_len(&baked.btf[0]) + 3;
        let err =
            write_atomic_with_hook(&path, &baked, limit, Packing::Plain, |_| Ok(())).unwrap_err();
        match err {
            FormatError::AbsurdSize { field, value, .. } => {
                assert!(field.contains("btf image sets record 0"), "{field}");
                assert_eq!(value, btf_record_len(&baked.btf[0]));
            }
            other => panic!("expected an absurd size, got {other:?}"),
        }
        assert!(dir_entries(&dir).is_empty(), "nothing written");
        // One more byte of room and it is written, one record per section.
        write_atomic_with_hook(&path, &baked, limit + 1, Packing::Plain, |_| Ok(())).unwrap();
        let bytes = fs::read(&path).unwrap();
        // Two btf sections, the vcm sets together, the texel volume, the impostor, the
        // surfel tree.
        assert_eq!(section_count(&bytes), 6);
        assert!(from_bytes(&bytes).unwrap() == baked);
        fs::remove_dir_all(&dir).unwrap();
    }
}
