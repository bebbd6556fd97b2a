//! Sizes: the bytes of each record and of a whole file, and the packing of records into
//! sections of at most [`MAX_SECTION_BYTES`] that the writer follows.

use super::*;

/// One section the writer will emit: `count` records of `kind` starting at record `first`.
#[derive(Debug)]
pub(super) struct PlannedSection {
    pub(super) kind: SectionKind,
    pub(super) first: usize,
    pub(super) count: usize,
    /// Payload length in bytes.
    pub(super) len: u64,
}

pub(super) fn btf_record_len(set: &BtfImageSet) -> u64 {
    BTF_RECORD_FIXED_BYTES + set.direct.len() as u64 + set.ambient.len() as u64
}

pub(super) fn vcm_record_len(set: &VcmSet) -> u64 {
    VCM_RECORD_FIXED_BYTES + set.opacity.len() as u64
}

pub(super) fn texel_record_len(t: &TexelVolume) -> u64 {
    TEXEL_RECORD_FIXED_BYTES + t.voxels.len() as u64
}

pub(super) fn impostor_record_len(i: &Impostor) -> u64 {
    IMPOSTOR_RECORD_FIXED_BYTES + i.albedo.len() as u64 + i.normal_depth.len() as u64
}

/// Bytes of a surfel tree record of these counts.
pub fn surfel_record_bytes(levels: u32, nodes: u32, surfels: u64, density_dims: [u32; 3]) -> u64 {
    surfel::SURFEL_RECORD_FIXED_BYTES + SurfelSet::data_bytes(levels, nodes, surfels, density_dims)
}

/// Bytes of an impostor record of these sizes (both atlases, `mip_levels` levels each),
/// saturating on overflow.
pub fn impostor_record_bytes(frames: u32, resolution: u32, mip_levels: u32) -> u64 {
    Impostor::atlas_bytes(frames, resolution, mip_levels)
        .and_then(|a| a.checked_mul(2))
        .map_or(u64::MAX, |a| a.saturating_add(IMPOSTOR_RECORD_FIXED_BYTES))
}

/// Bytes of a BTF image-set record of these sizes, its images in RGBA8 or (`compress`)
/// as BC7 mip chains.
pub fn btf_record_bytes(views: u32, lights: u32, resolution: u32, compress: bool) -> u64 {
    let image = if compress {
        bc::bc7_chain_bytes(resolution)
    } else {
        u64::from(resolution).pow(2) * 4
    };
    let per_view = u64::from(lights) + u64::from(AMBIENT_IMAGES_PER_VIEW);
    BTF_RECORD_FIXED_BYTES + u64::from(views) * per_view * image
}

/// Bytes of a VCM set record (8 corners x 6 faces) of this face resolution, a byte a
/// texel or (`compress`) in BC4.
pub fn vcm_record_bytes(resolution: u32, compress: bool) -> u64 {
    let face = if compress {
        bc::bc4_bytes(resolution, resolution)
    } else {
        u64::from(resolution).pow(2)
    };
    VCM_RECORD_FIXED_BYTES + 8 * 6 * face
}

/// Bytes of a texel volume record with `lights` light volumes (and the sky's) of `dims`.
pub fn texel_record_bytes(lights: u32, dims: [u32; 3]) -> u64 {
    let voxels: u64 = dims.iter().map(|&d| u64::from(d)).product();
    TEXEL_RECORD_FIXED_BYTES + (u64::from(lights) + 1) * voxels * 4
}

/// The length of the file the writer makes of records of these sizes (each list in file
/// order: BTF sets, VCM sets, texel volumes, impostors, surfel trees), or `Err` with the size of a
/// record too large for any section ([`MAX_SECTION_BYTES`]).
pub fn file_bytes_for(
    btf: &[u64],
    vcm: &[u64],
    texel: &[u64],
    impostor: &[u64],
    surfel: &[u64],
) -> Result<u64, u64> {
    if let Some(&big) = btf
        .iter()
        .chain(vcm)
        .chain(texel)
        .chain(impostor)
        .chain(surfel)
        .find(|&&s| s.saturating_add(SECTION_PREFIX_BYTES) > MAX_SECTION_BYTES)
    {
        return Err(big);
    }
    let mut plans = Vec::new();
    for (kind, sizes) in [
        (SectionKind::Btf, btf),
        (SectionKind::Vcm, vcm),
        (SectionKind::Texel, texel),
        (SectionKind::Impostor, impostor),
        (SectionKind::Surfel, surfel),
    ] {
        pack(kind, sizes.iter().copied(), MAX_SECTION_BYTES, &mut plans);
    }
    let payloads: u64 = plans.iter().map(|p| p.len).sum();
    Ok((FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * plans.len() + 4) as u64 + payloads)
}

/// Packs records into sections greedily, each at most `limit` bytes unless one record alone
/// is larger (which [`Baked::validate`] rejects).
pub(super) fn plan_sections(baked: &Baked, limit: u64) -> Vec<PlannedSection> {
    let mut plans = Vec::new();
    pack(
        SectionKind::Btf,
        baked.btf.iter().map(btf_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Vcm,
        baked.vcm.iter().map(vcm_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Texel,
        baked.texels.iter().map(texel_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Impostor,
        baked.impostors.iter().map(impostor_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Surfel,
        baked.surfels.iter().map(SurfelSet::record_bytes),
        limit,
        &mut plans,
    );
    plans
}

fn pack(
    kind: SectionKind,
    sizes: impl Iterator<Item = u64>,
    limit: u64,
    out: &mut Vec<PlannedSection>,
) {
    let mut current: Option<PlannedSection> = None;
    for (i, size) in sizes.enumerate() {
        match &mut current {
            Some(c) if c.len.saturating_add(size) <= limit && c.count < u32::MAX as usize => {
                c.count += 1;
                c.len += size;
            }
            _ => {
                out.extend(current.take());
                current = Some(PlannedSection {
                    kind,
                    first: i,
                    count: 1,
                    len: SECTION_PREFIX_BYTES.saturating_add(size),
                });
            }
        }
    }
    out.extend(current);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::test_support::*;
    use crate::format::to_bytes;

    #[test]
    fn the_file_size_is_known_from_the_record_sizes_alone() {
        let mut compressed = sample();
        crate::format::test_support::compress_for_tests(&mut compressed);
        for b in [sample(), small(), compressed] {
            let btf: Vec<u64> = b
                .btf
                .iter()
                .map(|s| {
                    let bc7 = s.encoding == ImageEncoding::Bc7;
                    btf_record_bytes(s.views, s.lights, s.resolution, bc7)
                })
                .collect();
            let vcm: Vec<u64> = b
                .vcm
                .iter()
                .map(|s| vcm_record_bytes(s.resolution, s.encoding == MapEncoding::Bc4))
                .collect();
            let texel: Vec<u64> = b
                .texels
                .iter()
                .map(|t| texel_record_bytes(t.lights, t.dims))
                .collect();
            let impostor: Vec<u64> = b
                .impostors
                .iter()
                .map(|i| impostor_record_bytes(i.frames, i.resolution, i.mip_levels))
                .collect();
            let surfel: Vec<u64> = b
                .surfels
                .iter()
                .map(|t| {
                    let levels = t.levels() as u32;
                    surfel_record_bytes(
                        levels,
                        t.nodes.len() as u32,
                        t.surfel_count(),
                        t.density.dims,
                    )
                })
                .collect();
            assert_eq!(
                file_bytes_for(&btf, &vcm, &texel, &impostor, &surfel),
                Ok(to_bytes(&b).len() as u64)
            );
        }
        // 258 views x 258 lights at 128² is one 4.4 GB record: no section holds it.
        let huge = btf_record_bytes(258, 258, 128, false);
        assert_eq!(file_bytes_for(&[huge], &[], &[], &[], &[]), Err(huge));
        // The largest impostor (32 x 32 frames of 256², every level) fits a section.
        let most = impostor_record_bytes(32, 256, impostor_mip_levels(256));
        assert!(most + 4 <= MAX_SECTION_BYTES, "{most}");
        assert_eq!(
            file_bytes_for(&[], &[], &[], &[most], &[]).map(|_| ()),
            Ok(())
        );
    }
}
