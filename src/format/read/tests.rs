//! The decoder's tests: every corrupt, truncated or absurd input is an error, never a panic
//! or an allocation beyond the input's size.

use super::*;
use crate::format::test_support::*;
use crate::format::to_bytes;
use std::fs;

mod packing;
mod surfel;

#[test]
fn flipped_payload_byte_is_a_checksum_mismatch() {
    let mut bytes = to_bytes(&sample());
    // In the middle of the first BTF set's direct images.
    let at = payload_start(&bytes, 0) + 4 + 48 + 1000;
    bytes[at] ^= 0x10;
    match from_bytes(&bytes) {
        Err(FormatError::ChecksumMismatch { section, .. }) => {
            assert_eq!(section, "section 0 (btf image sets)")
        }
        other => panic!("expected a checksum mismatch, got {other:?}"),
    }
    // And in the VCM section, inside a length field (the decode fails, the checksum
    // is still what is reported).
    let mut bytes = to_bytes(&sample());
    let at = payload_start(&bytes, 1) + 4 + 44 + 2;
    bytes[at] ^= 0x01;
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::ChecksumMismatch { section, .. }) if section == "section 1 (vcm sets)"
    ));
}

#[test]
fn flipped_header_byte_is_a_checksum_mismatch() {
    let clean = to_bytes(&sample());
    // scene hash, settings, a section crc, a section length, the header crc itself
    for at in [
        24,
        33,
        48,
        57,
        61,
        69,
        72 + 5,
        72 + 16 + 8,
        header_end(&clean) + 1,
    ] {
        let mut bytes = clean.clone();
        bytes[at] ^= 0x01;
        match from_bytes(&bytes) {
            Err(FormatError::ChecksumMismatch { section, .. }) => {
                assert_eq!(section, "header", "byte {at}")
            }
            other => panic!("byte {at}: expected a header checksum mismatch, got {other:?}"),
        }
    }
}

#[test]
fn every_flipped_byte_of_a_small_file_is_detected() {
    let clean = to_bytes(&small());
    let header_end = header_end(&clean) + 4;
    for at in 0..clean.len() {
        for mask in [0x01, 0x80] {
            let mut bytes = clean.clone();
            bytes[at] ^= mask;
            let (result, peak) = peak_during(|| from_bytes(&bytes));
            assert!(peak <= bytes.len() + SMALL_OVERHEAD);
            let ok = match (&result, at) {
                (Err(FormatError::NotCanopy { .. }), 0..8) => true,
                (Err(FormatError::UnsupportedVersion { .. }), 8..12) => true,
                (
                    Err(
                        FormatError::AbsurdSize { .. }
                        | FormatError::Truncated { .. }
                        | FormatError::ChecksumMismatch { .. },
                    ),
                    12..16,
                ) => true,
                (Err(FormatError::ChecksumMismatch { section, .. }), _) if at < header_end => {
                    section == "header"
                }
                (Err(FormatError::ChecksumMismatch { section, .. }), _) => {
                    section.starts_with("section ")
                }
                _ => false,
            };
            assert!(ok, "byte {at} ^ {mask:#x}: {result:?}");
        }
    }
}

#[test]
fn every_truncation_is_an_error() {
    for bytes in [to_bytes(&small()), to_bytes(&sample())] {
        for len in 0..bytes.len() {
            let prefix = &bytes[..len];
            let (result, peak) = peak_during(|| from_bytes(prefix));
            assert!(
                matches!(result, Err(FormatError::Truncated { .. })),
                "prefix of {len} bytes: {result:?}"
            );
            assert!(peak <= len + SMALL_OVERHEAD, "prefix of {len}: held {peak}");
        }
        assert!(from_bytes(&bytes).is_ok());
    }
}

/// Truncations whose header, lengths and checksums were all made consistent again, so
/// only the record decoding can notice.
#[test]
fn truncation_with_a_consistent_header_is_an_error() {
    let bytes = to_bytes(&small());
    let head = header_end(&bytes) + 4;
    for len in head..bytes.len() {
        let mut cut = bytes[..len].to_vec();
        cut[16..24].copy_from_slice(&(len as u64).to_le_bytes());
        let mut left = (len - head) as u64;
        for i in 0..section_count(&cut) {
            let at = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i + 8;
            let section_len = u64_at(&cut, at).min(left);
            cut[at..at + 8].copy_from_slice(&section_len.to_le_bytes());
            cut[at + 12..at + 20].copy_from_slice(&section_len.to_le_bytes());
            left -= section_len;
        }
        reseal(&mut cut);
        let (result, peak) = peak_during(|| from_bytes(&cut));
        assert!(
            matches!(result, Err(FormatError::MalformedContent { .. })),
            "cut at {len}: {result:?}"
        );
        assert!(peak <= len + SMALL_OVERHEAD);
    }
}

#[test]
fn wrong_magic_is_not_a_canopy_file() {
    let mut bytes = to_bytes(&small());
    bytes[0] = b'X';
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::NotCanopy { .. })
    ));
    assert!(matches!(
        from_bytes(b"PNG\x89 not at all"),
        Err(FormatError::NotCanopy { found }) if found == b"PNG\x89 not"
    ));
    // Line endings converted CRLF -> LF in transfer.
    let clean = to_bytes(&small());
    let mangled: Vec<u8> = clean[..6].iter().chain(&clean[7..]).copied().collect();
    let err = from_bytes(&mangled).unwrap_err();
    assert!(matches!(err, FormatError::NotCanopy { .. }), "{err:?}");
    assert!(err.to_string().contains("canopy bake"), "{err}");
    // A short file that is not ours is "not a canopy file", not "truncated".
    assert!(matches!(
        from_bytes(b"{}"),
        Err(FormatError::NotCanopy { .. })
    ));
}

#[test]
fn wrong_version_is_unsupported() {
    // Version 6 is the last one before block compression, 5 the last before impostors:
    // their files are refused, with the hint; so is a version from the future.
    for version in [0u32, 1, 2, 3, 4, 5, 6, 10, u32::MAX] {
        let mut bytes = to_bytes(&small());
        bytes[8..12].copy_from_slice(&version.to_le_bytes());
        reseal_header(&mut bytes);
        match from_bytes(&bytes) {
            Err(
                e @ FormatError::UnsupportedVersion {
                    found,
                    oldest,
                    supported,
                },
            ) => {
                assert_eq!((found, oldest, supported), (version, 7, VERSION));
                assert!(e.to_string().contains("reads versions 7 to 9"), "{e}");
                assert!(e.to_string().contains("re-bake with `canopy bake`"), "{e}");
                assert!(e.needs_rebake());
            }
            other => panic!("version {version}: {other:?}"),
        }
    }
}

#[test]
fn absurd_section_length_is_rejected_before_allocating() {
    let mut bytes = to_bytes(&sample());
    let at = FIXED_HEADER_BYTES + 8; // length of section 0
    bytes[at..at + 8].copy_from_slice(&0xFFFF_FFFF_FFFFu64.to_le_bytes());
    reseal_header(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    match result {
        Err(FormatError::AbsurdSize {
            field,
            value,
            limit,
        }) => {
            assert!(field.contains("section 0"), "{field}");
            assert_eq!((value, limit), (0xFFFF_FFFF_FFFF, MAX_SECTION_BYTES));
        }
        other => panic!("expected an absurd size, got {other:?}"),
    }
    assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
}

#[test]
fn absurd_section_count_is_rejected_before_allocating() {
    let mut bytes = to_bytes(&small());
    bytes[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(result, Err(FormatError::AbsurdSize { value, .. }) if value == u32::MAX as u64),
        "{result:?}"
    );
    assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
}

#[test]
fn a_record_claiming_huge_images_is_malformed_without_allocating() {
    // 258 views x 258 lights at 128²: a consistent 4.4 GB claim in a 350 KB file.
    let mut bytes = to_bytes(&sample());
    let record = payload_start(&bytes, 0) + 4;
    let direct_len: u64 = 258 * 258 * 128 * 128 * 4;
    bytes[record + 8..record + 12].copy_from_slice(&258u32.to_le_bytes());
    bytes[record + 12..record + 16].copy_from_slice(&258u32.to_le_bytes());
    bytes[record + 16..record + 20].copy_from_slice(&128u32.to_le_bytes());
    bytes[record + 40..record + 48].copy_from_slice(&direct_len.to_le_bytes());
    reseal(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { reason, .. })
            if reason.contains(&direct_len.to_string())),
        "{result:?}"
    );
    assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
}

#[test]
fn absurd_record_count_is_malformed_without_allocating() {
    let mut bytes = to_bytes(&small());
    let at = payload_start(&bytes, 0);
    bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    reseal(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { reason, .. }) if reason.contains("records cannot fit")),
        "{result:?}"
    );
    assert!(peak < SMALL_OVERHEAD);
}

#[test]
fn inconsistent_payload_with_valid_checksums_is_malformed() {
    // direct one byte short: to_bytes writes it faithfully, with correct checksums.
    let mut baked = sample();
    baked.btf[1].direct.pop();
    assert!(matches!(
        baked.validate(),
        Err(FormatError::MalformedContent { .. })
    ));
    let bytes = to_bytes(&baked);
    match from_bytes(&bytes) {
        Err(FormatError::MalformedContent { section, reason }) => {
            assert_eq!(section, "section 0 (btf image sets)");
            assert!(reason.contains("direct"), "{reason}");
        }
        other => panic!("expected malformed content, got {other:?}"),
    }

    // Ambient of the wrong size, radius not positive, texel size NaN, VCM too short,
    // mean opacity out of range: each caught on write and on read.
    // Texel volumes: voxels one byte short, a zero or huge dimension, a NaN corner, a
    // negative voxel, a light count that is no direction set.
    // Impostors: an atlas one byte short, the two atlases of different sizes, frames,
    // resolution or levels out of range, a NaN centre, an infinite radius.
    let breakers: [fn(&mut Baked); 20] = [
        |b| b.texels[0].voxels.pop().map_or((), drop),
        |b| b.texels[0].dims[1] = 0,
        |b| b.texels[0].dims[2] = 100_000,
        |b| b.texels[0].box_min[0] = f32::NAN,
        |b| b.texels[0].voxel = -0.25,
        |b| b.texels[0].lights = 5,
        |b| b.btf[0].ambient.extend([0; 4]),
        |b| b.btf[0].radius = 0.0,
        |b| b.btf[1].texel_size = f32::NAN,
        |b| b.vcm[1].opacity.truncate(10),
        |b| b.vcm[0].mean_opacity[3] = 1.5,
        |b| b.impostors[0].albedo.pop().map_or((), drop),
        |b| b.impostors[0].normal_depth.extend([0; 4]),
        |b| b.impostors[0].frames = 3,
        |b| b.impostors[0].frames = 64,
        |b| b.impostors[0].resolution = 24,
        |b| b.impostors[0].mip_levels = 0,
        |b| b.impostors[0].mip_levels = 4,
        |b| b.impostors[0].center[2] = f32::NAN,
        |b| b.impostors[0].radius = f32::INFINITY,
    ];
    for (i, breaker) in breakers.iter().enumerate() {
        let mut baked = sample();
        breaker(&mut baked);
        assert!(
            matches!(baked.validate(), Err(FormatError::MalformedContent { .. })),
            "breaker {i} on write"
        );
        let result = from_bytes(&to_bytes(&baked));
        assert!(
            matches!(result, Err(FormatError::MalformedContent { .. })),
            "breaker {i} on read: {result:?}"
        );
    }

    // A level byte that names no level, checksums recomputed.
    let mut bytes = to_bytes(&small());
    let at = payload_start(&bytes, 0) + 4 + 8; // record count, species, owner
    bytes[at] = 3;
    reseal(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("level 3")
    ));

    // A record count lower than the records present: bytes left over in the section.
    let mut bytes = to_bytes(&small());
    let at = payload_start(&bytes, 0);
    bytes[at..at + 4].copy_from_slice(&1u32.to_le_bytes());
    reseal(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("left after the last record")
    ));

    // The same species' texel volume twice.
    let mut baked = sample();
    baked.texels.push(baked.texels[0].clone());
    assert!(baked.validate().is_err());
    assert!(matches!(
        from_bytes(&to_bytes(&baked)),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
    ));

    // The same species' impostor twice.
    let mut baked = sample();
    baked.impostors.push(baked.impostors[0].clone());
    assert!(baked.validate().is_err());
    assert!(matches!(
        from_bytes(&to_bytes(&baked)),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
    ));

    // The same BTF set twice.
    let mut baked = sample();
    baked.btf[1] = baked.btf[0].clone();
    assert!(baked.validate().is_err());
    assert!(matches!(
        from_bytes(&to_bytes(&baked)),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
    ));
}

#[test]
fn trailing_bytes_are_malformed() {
    let mut bytes = to_bytes(&small());
    bytes.extend_from_slice(b"junk");
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { .. })
    ));
}

#[test]
fn read_expecting_another_hash_is_a_scene_mismatch() {
    let dir = scratch_dir("mismatch");
    let path = dir.join("a.canopy");
    let baked = small();
    write_atomic(&path, &baked).unwrap();
    let err = read_expecting(&path, baked.scene_hash ^ 1).unwrap_err();
    match &err {
        FormatError::SceneMismatch { found, expected } => {
            assert_eq!(
                (*found, *expected),
                (baked.scene_hash, baked.scene_hash ^ 1)
            )
        }
        other => panic!("expected a scene mismatch, got {other:?}"),
    }
    assert!(err.needs_rebake());
    assert!(err.to_string().contains("canopy bake"));
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn reading_a_missing_file_is_an_io_error_naming_it() {
    let dir = scratch_dir("missing");
    let path = dir.join("absent.canopy");
    let err = read(&path).unwrap_err();
    assert!(err.is_not_found(), "{err:?}");
    assert!(!err.needs_rebake());
    assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
    fs::remove_dir_all(&dir).unwrap();
}

/// The impostor section (kind 4, the last but one of `sample`'s sections): every count and size is
/// checked against the section before anything is allocated, with the checksums made
/// right again so only the decoding can notice.
#[test]
fn corrupt_impostor_records_are_malformed_without_allocating() {
    let clean = to_bytes(&sample());
    let last = section_count(&clean) - 2;
    let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * last;
    assert_eq!(u32_at(&clean, entry), SectionKind::Impostor as u32);
    let record = payload_start(&clean, last) + 4;
    // (offset in the record, value, what the reason names)
    let cases: [(usize, u64, &str); 6] = [
        (4, 9, "layout 9"),
        (8, 32, "albedo holds"),
        (12, 256, "albedo holds"),
        (16, 40, "mip_levels"),
        (36, u64::MAX, "albedo holds"),
        (36, 1 << 40, "albedo holds"),
    ];
    for (at, value, want) in cases {
        let mut bytes = clean.clone();
        let at = record + at;
        if at == record + 36 {
            bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
        } else {
            bytes[at..at + 4].copy_from_slice(&(value as u32).to_le_bytes());
        }
        reseal(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        match result {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert!(section.contains("impostors"), "{section}");
                assert!(reason.contains(want), "{want:?} in {reason}");
            }
            other => panic!("{at}={value}: expected malformed content, got {other:?}"),
        }
        assert!(peak <= bytes.len() + SMALL_OVERHEAD, "held {peak}");
    }
    // A record count of more records than the section could hold.
    let mut bytes = clean.clone();
    bytes[record - 4..record].copy_from_slice(&u32::MAX.to_le_bytes());
    reseal(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { reason, .. }) if reason.contains("cannot fit")),
        "{result:?}"
    );
    assert!(peak <= bytes.len() + SMALL_OVERHEAD);
    // The normal-depth length disagreeing with the albedo's.
    let mut bytes = clean.clone();
    let albedo_len = u64_at(&bytes, record + 36) as usize;
    let at = record + 44 + albedo_len;
    bytes[at..at + 8].copy_from_slice(&7u64.to_le_bytes());
    reseal(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("normal_depth holds 7")
    ));
    // Unresealed, a flipped byte in the atlases is the impostor section's checksum.
    let mut bytes = clean.clone();
    bytes[record + 44 + 100] ^= 0x08;
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::ChecksumMismatch { section, .. }) if section.contains("impostors")
    ));
    // The header's impostor layout naming none.
    let mut bytes = clean.clone();
    bytes[68..72].copy_from_slice(&2u32.to_le_bytes());
    reseal_header(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::InvalidSettings {
            field: "impostor_layout",
            value: 2,
            ..
        })
    ));
}

/// A compressed bake (BC7 images, BC4 cube maps): a flipped byte in its blocks is its
/// section's checksum; an encoding byte naming none, or one that does not fit the lengths
/// that follow, is malformed before anything is allocated; the header's compress word must
/// be 0 or 1.
#[test]
fn corrupt_compressed_records_are_refused_without_allocating() {
    let mut baked = sample();
    crate::format::test_support::compress_for_tests(&mut baked);
    let clean = to_bytes(&baked);
    assert_eq!(from_bytes(&clean).unwrap(), baked);
    let btf = payload_start(&clean, 0) + 4;
    let vcm = payload_start(&clean, 1) + 4;
    assert_eq!(clean[btf + 5], ImageEncoding::Bc7.tag());
    assert_eq!(clean[vcm + 9], MapEncoding::Bc4.tag());
    // Flipped block bytes: the checksums.
    for (at, section) in [(btf + 48 + 700, "section 0"), (vcm + 56 + 30, "section 1")] {
        let mut bytes = clean.clone();
        bytes[at] ^= 0x20;
        match from_bytes(&bytes) {
            Err(FormatError::ChecksumMismatch { section: s, .. }) => {
                assert!(s.starts_with(section), "{s}")
            }
            other => panic!("byte {at}: expected a checksum mismatch, got {other:?}"),
        }
    }
    // (offset, encoding byte, what the reason names), the checksums made right again.
    let cases = [
        (btf + 5, 2, "encoding 2"),
        (btf + 5, ImageEncoding::Rgba8.tag(), "direct holds"),
        (vcm + 9, 7, "encoding 7"),
        (vcm + 9, MapEncoding::R8.tag(), "opacity holds"),
    ];
    for (at, tag, want) in cases {
        let mut bytes = clean.clone();
        bytes[at] = tag;
        reseal(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        match result {
            Err(FormatError::MalformedContent { reason, .. }) => {
                assert!(reason.contains(want), "{want:?} in {reason}")
            }
            other => panic!("{at}={tag}: expected malformed content, got {other:?}"),
        }
        assert!(peak <= bytes.len() + SMALL_OVERHEAD, "held {peak}");
    }
    // A BC7 record claiming a huge image count: refused before allocating.
    let mut bytes = clean.clone();
    bytes[btf + 8..btf + 12].copy_from_slice(&258u32.to_le_bytes());
    bytes[btf + 12..btf + 16].copy_from_slice(&258u32.to_le_bytes());
    bytes[btf + 40..btf + 48].copy_from_slice(&(258u64 * 258 * 5456).to_le_bytes());
    reseal(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { .. })),
        "{result:?}"
    );
    assert!(peak <= bytes.len() + SMALL_OVERHEAD, "held {peak}");
    // The header's compress word.
    let mut bytes = clean.clone();
    bytes[72..76].copy_from_slice(&2u32.to_le_bytes());
    reseal_header(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::InvalidSettings {
            field: "compress",
            value: 2,
            ..
        })
    ));
}
