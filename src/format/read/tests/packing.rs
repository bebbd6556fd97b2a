//! The section table's two layouts and its packing: version-7 files, deflated sections
//! (round trip, corruption, streams that disagree with their entries, allocation as they
//! inflate) and `sections`.

use super::*;
use crate::format::to_bytes_packed;

/// A version-7 file (no surfel budget, 16-byte table entries, nothing deflated) reads as
/// the same bake.
#[test]
fn a_version_7_file_reads() {
    let mut baked = sample();
    baked.settings.surfel_budget = 0;
    let v7 = as_version_7(&to_bytes(&baked));
    assert_eq!(u32_at(&v7, 8), 7);
    assert_eq!(
        v7.len(),
        to_bytes(&baked).len() - 4 - 12 * section_count(&v7),
        "no surfel budget, and four bytes of packing and eight of inflated length less per entry"
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
            SectionKind::Impostor,
            SectionKind::Surfel
        ]
    );
    let file_len = fs::metadata(&path).unwrap().len();
    let stored: u64 = list.iter().map(|s| s.stored_bytes).sum();
    assert_eq!(
        stored + (FIXED_HEADER_BYTES + 5 * SECTION_ENTRY_BYTES + 4) as u64,
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
