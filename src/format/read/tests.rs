//! The decoder's tests: every corrupt, truncated or absurd input is an error, never a panic
//! or an allocation beyond the input's size.

use super::*;
use crate::format::test_support::*;
use crate::format::{to_bytes, to_bytes_packed};
use std::fs;

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
    for version in [0u32, 1, 2, 3, 4, 5, 6, 9, u32::MAX] {
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
                assert!(e.to_string().contains("reads versions 7 to 8"), "{e}");
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

/// The impostor section (kind 4, the last of `sample`'s sections): every count and size is
/// checked against the section before anything is allocated, with the checksums made
/// right again so only the decoding can notice.
#[test]
fn corrupt_impostor_records_are_malformed_without_allocating() {
    let clean = to_bytes(&sample());
    let last = section_count(&clean) - 1;
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

/// A version-7 file (16-byte table entries, nothing deflated) reads as the same bake.
#[test]
fn a_version_7_file_reads() {
    let baked = sample();
    let v7 = as_version_7(&to_bytes(&baked));
    assert_eq!(u32_at(&v7, 8), 7);
    assert_eq!(
        v7.len(),
        to_bytes(&baked).len() - 12 * section_count(&v7),
        "four bytes of packing and eight of inflated length less per entry"
    );
    let (back, peak) = peak_during(|| from_bytes(&v7).unwrap());
    assert!(back == baked);
    assert!(peak <= v7.len() + SMALL_OVERHEAD, "held {peak}");
    // Its bytes are checked as a version-8 file's are.
    let mut bad = v7.clone();
    let last = bad.len() - 10;
    bad[last] ^= 0x10;
    assert!(matches!(
        from_bytes(&bad),
        Err(FormatError::ChecksumMismatch { section, .. }) if section.starts_with("section ")
    ));
}

/// Deflated sections read back as the same bake, in less space, holding no more than the
/// decoded data; a section that does not shrink stays plain.
#[test]
fn deflated_sections_round_trip_smaller() {
    let baked = compressible(sample());
    let plain = to_bytes(&baked);
    let packed = to_bytes_packed(&baked, Packing::Deflate);
    let n = section_count(&packed);
    for i in 0..n {
        let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
        assert_eq!(
            u32_at(&packed, entry + 16),
            Packing::Deflate as u32,
            "section {i}"
        );
        assert!(u64_at(&packed, entry + 8) < u64_at(&packed, entry + 20) * 3 / 4);
        assert_eq!(u64_at(&packed, entry + 20), u64_at(&plain, entry + 8));
    }
    assert!(
        packed.len() < plain.len() * 3 / 4,
        "{} of {}",
        packed.len(),
        plain.len()
    );
    let (back, peak) = peak_during(|| from_bytes(&packed).unwrap());
    assert!(back == baked, "decoded data differs from what was encoded");
    assert!(peak <= plain.len() + SMALL_OVERHEAD, "held {peak}");
    assert_eq!(
        to_bytes_packed(&baked, Packing::Deflate),
        packed,
        "deterministic"
    );

    // A section of noise does not shrink: stored as it is.
    let noisy = to_bytes_packed(&sample(), Packing::Deflate);
    let mut plain_sections = 0;
    for i in 0..section_count(&noisy) {
        let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
        let (len, plain_len) = (u64_at(&noisy, entry + 8), u64_at(&noisy, entry + 20));
        if u32_at(&noisy, entry + 16) == Packing::Plain as u32 {
            assert_eq!(len, plain_len);
            plain_sections += 1;
        } else {
            assert!(len < plain_len);
        }
    }
    assert!(plain_sections > 0);
    assert!(from_bytes(&noisy).unwrap() == sample());
}

/// Every flipped byte of a deflated file is found (the stored bytes' checksum), and so is
/// every truncation.
#[test]
fn every_flipped_byte_and_truncation_of_a_deflated_file_is_detected() {
    let clean = to_bytes_packed(&compressible(small()), Packing::Deflate);
    assert_eq!(
        u32_at(&clean, FIXED_HEADER_BYTES + 16),
        Packing::Deflate as u32
    );
    let header_end = header_end(&clean) + 4;
    for at in 12..clean.len() {
        let mut bytes = clean.clone();
        bytes[at] ^= 0x04;
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        assert!(
            peak <= clean.len() * 4 + SMALL_OVERHEAD,
            "byte {at}: held {peak}"
        );
        let ok = match &result {
            Err(FormatError::ChecksumMismatch { section, .. }) if at < header_end => {
                section == "header"
            }
            Err(FormatError::ChecksumMismatch { section, .. }) => section.starts_with("section "),
            Err(FormatError::AbsurdSize { .. } | FormatError::Truncated { .. }) => at < 16,
            _ => false,
        };
        assert!(ok, "byte {at}: {result:?}");
    }
    for len in 0..clean.len() {
        assert!(matches!(
            from_bytes(&clean[..len]),
            Err(FormatError::Truncated { .. })
        ));
    }
}

/// A deflated section whose checksum is right but whose stream is wrong: not DEFLATE, too
/// short or too long for its inflated length, bytes after the stream's end; and table
/// entries naming no packing or disagreeing with themselves. Each is malformed, named, and
/// nothing is allocated from the promised length.
#[test]
fn a_deflated_section_that_does_not_inflate_as_its_entry_says_is_malformed() {
    let plain = to_bytes(&compressible(small()));
    let payload = payloads(&plain)[0].clone();
    let plain_len = payload.len() as u64;
    let good = deflate(&payload);
    let mut trailing = good.clone();
    trailing.extend_from_slice(&[0, 0, 0]);
    let mut garbage = good.clone();
    garbage[0] = 0xFF; // block type 3: reserved
    let mut extended = payload.clone();
    extended.extend_from_slice(&[0; 5]);
    let longer = deflate(&extended);
    let cases: [(&[u8], u64, &str); 6] = [
        (&garbage, plain_len, "does not inflate"),
        (
            &good,
            plain_len + 1,
            "1 bytes are left after the last record",
        ),
        (&good, plain_len - 1, "but the section has only"),
        (&longer, plain_len, "more than"),
        (&good, 1 << 30, "left after the last record"),
        (&trailing, plain_len, "3 bytes follow"),
    ];
    for (stored, claimed, want) in cases {
        let bytes = with_section(&plain, 0, stored, Packing::Deflate, claimed);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        match result {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert!(section.starts_with("section 0"), "{section}");
                assert!(reason.contains(want), "{want:?} in {reason}");
            }
            other => panic!("{want}: expected malformed content, got {other:?}"),
        }
        assert!(
            peak <= plain.len() + 4 * SMALL_OVERHEAD,
            "{want}: held {peak}"
        );
    }
    // The right stream reads.
    let bytes = with_section(&plain, 0, &good, Packing::Deflate, plain_len);
    assert!(from_bytes(&bytes).unwrap() == compressible(small()));
    // A packing that names none, a plain section whose two lengths disagree, an inflated
    // length over the limit.
    let entry = FIXED_HEADER_BYTES + 16;
    let mut bytes = plain.clone();
    bytes[entry..entry + 4].copy_from_slice(&2u32.to_le_bytes());
    reseal_header(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("packing 2")
    ));
    let mut bytes = plain.clone();
    bytes[entry + 4..entry + 12].copy_from_slice(&(plain_len + 8).to_le_bytes());
    reseal_header(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("inflated length says")
    ));
    let mut bytes = with_section(&plain, 0, &good, Packing::Deflate, plain_len);
    bytes[entry + 4..entry + 12].copy_from_slice(&((1u64 << 30) + 1).to_le_bytes());
    reseal_header(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::AbsurdSize { field, .. }) if field.contains("inflated length")
    ));
}

/// A deflated texel record that claims 470 MB of voxels (allowed for its dims) in a
/// section that promises them, whose stream holds a few bytes: malformed, and what was
/// allocated follows what inflated (one step of 4 MiB), not the claim.
#[test]
fn a_deflated_record_claiming_much_allocates_as_it_inflates() {
    let plain = to_bytes(&compressible(small()));
    let texel_section = (0..section_count(&plain))
        .find(|&i| {
            u32_at(&plain, FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i)
                == SectionKind::Texel as u32
        })
        .unwrap();
    let lights = 6u32;
    let voxels = u64::from(lights + 1) * 256 * 256 * 256 * 4;
    let mut payload = Vec::new();
    payload.extend_from_slice(&1u32.to_le_bytes());
    for v in [1u32, lights, 256, 256, 256] {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    for f in [0.0f32, 0.0, 0.0, 0.1] {
        payload.extend_from_slice(&f.to_le_bytes());
    }
    payload.extend_from_slice(&voxels.to_le_bytes());
    payload.extend_from_slice(&[7; 64]);
    let claimed = payload.len() as u64 - 64 + voxels;
    let bytes = with_section(
        &plain,
        texel_section,
        &deflate(&payload),
        Packing::Deflate,
        claimed,
    );
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { reason, .. }) if reason.contains("does not inflate")),
        "{result:?}"
    );
    assert!(
        peak <= BYTES_STEP + plain.len() + 4 * SMALL_OVERHEAD,
        "held {peak}"
    );
}

/// `sections` reads the table of a file written by `write_atomic` (deflated where that
/// shrinks), and refuses a corrupt header as `read` does.
#[test]
fn sections_lists_what_the_file_holds() {
    let dir = scratch_dir("sections");
    let path = dir.join("b.canopy");
    let baked = compressible(sample());
    crate::format::write_atomic(&path, &baked).unwrap();
    let list = crate::format::sections(&path).unwrap();
    let plain = to_bytes(&baked);
    let kinds: Vec<SectionKind> = list.iter().map(|s| s.kind).collect();
    assert_eq!(
        kinds,
        [
            SectionKind::Btf,
            SectionKind::Vcm,
            SectionKind::Texel,
            SectionKind::Impostor
        ]
    );
    let file_len = fs::metadata(&path).unwrap().len();
    let stored: u64 = list.iter().map(|s| s.stored_bytes).sum();
    assert_eq!(
        stored + (FIXED_HEADER_BYTES + 4 * SECTION_ENTRY_BYTES + 4) as u64,
        file_len
    );
    for (i, s) in list.iter().enumerate() {
        let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
        assert_eq!(s.data_bytes, u64_at(&plain, entry + 8));
        assert_eq!(s.packing, Packing::Deflate);
        assert!(s.stored_bytes < s.data_bytes);
    }
    assert!(read(&path).unwrap() == baked);
    let mut bytes = fs::read(&path).unwrap();
    bytes[40] ^= 1;
    fs::write(&path, &bytes).unwrap();
    assert!(matches!(
        crate::format::sections(&path),
        Err(FormatError::ChecksumMismatch { section, .. }) if section == "header"
    ));
    fs::remove_dir_all(&dir).unwrap();
}
