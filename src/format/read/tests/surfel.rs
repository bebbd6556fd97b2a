//! The surfel tree section (kind 5, the last of `sample`'s sections): it round-trips, and
//! every count, size, index and value is checked, on write and on read, before anything is
//! sized from it.

use super::*;

#[test]
fn a_surfel_tree_round_trips() {
    let baked = sample();
    assert_eq!(baked.surfels.len(), 1);
    let back = from_bytes(&to_bytes(&baked)).unwrap();
    assert_eq!(back.surfels, baked.surfels);
    assert_eq!(back.settings.surfel_budget, baked.settings.surfel_budget);
    let t = &back.surfels[0];
    assert_eq!(t.roots, vec![1]);
    let s = unpack_surfel(
        [t.words[0], t.words[1], t.words[2]],
        t.bounds.min,
        t.bounds.extent(),
    );
    assert!((s.openness - 0.9).abs() < 0.01 && s.foliage, "{s:?}");
    assert_eq!(
        baked.surfel_bytes(),
        surfel_record_bytes(2, 2, 4, [2, 2, 2]),
        "the record's bytes"
    );
}

#[test]
fn broken_surfel_trees_are_refused_on_write_and_on_read() {
    // (what breaks it, what the reason names, whether the record it writes still has the
    // sizes its counts give, so that the reader reaches the same check)
    type Breaker = (fn(&mut SurfelSet), &'static str, bool);
    let breakers: [Breaker; 14] = [
        (|t| t.words.pop().map_or((), drop), "words", false),
        (|t| t.gains[1] = 0.5, "gain", true),
        (|t| t.gains[1] = f32::NAN, "gain", true),
        (|t| t.per_level[0] = 2, "count", true),
        (|t| t.nodes[0].count = 5, "node 0", true),
        (|t| t.nodes[1].first = u32::MAX, "node 1", true),
        (|t| t.nodes[1].children = vec![1], "child 1", true),
        (|t| t.nodes[1].children = vec![7], "child 7", true),
        (|t| t.nodes[0].level = 2, "level", true),
        (|t| t.density.sigma[3] = -1.0, "density", true),
        (|t| t.density.sigma.push(0.0), "density", false),
        (|t| t.spacing0 = 0.0, "spacing", true),
        (|t| t.bounds.max.x = f32::INFINITY, "box", true),
        (|t| t.density.dims[2] = 65, "density volume", false),
    ];
    for (i, (breaker, want, readable)) in breakers.iter().enumerate() {
        let mut baked = sample();
        breaker(&mut baked.surfels[0]);
        match baked.validate() {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert!(section.contains("surfel tree"), "breaker {i}: {section}");
                assert!(reason.contains(want), "breaker {i}: {want:?} in {reason}");
            }
            other => panic!("breaker {i} on write: {other:?}"),
        }
        if !readable {
            continue;
        }
        // Written anyway (`to_bytes` does not check), refused on read.
        match from_bytes(&to_bytes(&baked)) {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert!(section.contains("surfel trees"), "breaker {i}: {section}");
                assert!(reason.contains(want), "breaker {i}: {want:?} in {reason}");
            }
            other => panic!("breaker {i} on read: {other:?}"),
        }
    }
    // The same species twice.
    let mut baked = sample();
    baked.surfels.push(baked.surfels[0].clone());
    assert!(baked.validate().is_err());
    assert!(matches!(
        from_bytes(&to_bytes(&baked)),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
    ));
}

#[test]
fn corrupt_surfel_records_are_malformed_without_allocating() {
    let clean = to_bytes(&sample());
    let last = section_count(&clean) - 1;
    let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * last;
    assert_eq!(u32_at(&clean, entry), SectionKind::Surfel as u32);
    let record = payload_start(&clean, last) + 4;
    // (offset in the record, value, what the reason names); counts that would size the
    // data far past the section are caught by the data's length before it is read.
    let cases: [(usize, u64, &str); 8] = [
        (4, 0, "levels"),
        (4, 17, "levels"),
        (8, u64::from(u32::MAX), "data holds"),
        (12, u64::from(u32::MAX), "data holds"),
        (60, 0, "density volume"),
        (64, 1 << 20, "density volume"),
        (72, u64::MAX, "data holds"),
        (72, 1 << 40, "data holds"),
    ];
    for (at, value, want) in cases {
        let mut bytes = clean.clone();
        let at = record + at;
        if at == record + 72 {
            bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
        } else {
            bytes[at..at + 4].copy_from_slice(&(value as u32).to_le_bytes());
        }
        reseal(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        match result {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert!(section.contains("surfel trees"), "{section}");
                assert!(reason.contains(want), "{want:?} in {reason}");
            }
            other => panic!("{at}={value}: expected malformed content, got {other:?}"),
        }
        assert!(peak <= bytes.len() + SMALL_OVERHEAD, "held {peak}");
    }
    // A data length past the section's end (its counts grown to match).
    let mut bytes = clean.clone();
    let len = u64_at(&bytes, record + 72);
    bytes[record + 12..record + 16].copy_from_slice(&(4 + 1_000_000u32).to_le_bytes());
    bytes[record + 72..record + 80].copy_from_slice(&(len + 12_000_000).to_le_bytes());
    reseal(&mut bytes);
    let (result, peak) = peak_during(|| from_bytes(&bytes));
    assert!(
        matches!(&result, Err(FormatError::MalformedContent { reason, .. }) if reason.contains("section has only")),
        "{result:?}"
    );
    assert!(peak <= bytes.len() + SMALL_OVERHEAD, "held {peak}");
    // A child slot past the used ones that is not empty, and a flipped byte (checksum).
    let mut bytes = clean.clone();
    let node1 = record + 80 + 2 * 8 + 72;
    bytes[node1 + 40 + 4..node1 + 40 + 8].copy_from_slice(&0u32.to_le_bytes());
    reseal(&mut bytes);
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::MalformedContent { reason, .. }) if reason.contains("child slots")
    ));
    let mut bytes = clean.clone();
    bytes[record + 200] ^= 0x40;
    assert!(matches!(
        from_bytes(&bytes),
        Err(FormatError::ChecksumMismatch { section, .. }) if section.contains("surfel trees")
    ));
}

#[test]
fn a_version_8_file_reads_with_no_surfel_budget() {
    // Version 8: no surfel budget word, no surfel trees.
    let mut baked = small();
    baked.settings.surfel_budget = 0;
    let v9 = to_bytes(&baked);
    let mut v8 = v9[..FIXED_HEADER_BYTES_V8].to_vec();
    v8.extend_from_slice(&v9[FIXED_HEADER_BYTES..]);
    v8[8..12].copy_from_slice(&8u32.to_le_bytes());
    let len = v8.len() as u64;
    v8[16..24].copy_from_slice(&len.to_le_bytes());
    let table_end = FIXED_HEADER_BYTES_V8 + SECTION_ENTRY_BYTES * section_count(&v8);
    let crc = crc32fast::hash(&v8[..table_end]);
    v8[table_end..table_end + 4].copy_from_slice(&crc.to_le_bytes());
    let back = from_bytes(&v8).unwrap();
    assert_eq!(back, baked);
}
