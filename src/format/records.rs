//! The data one bake produces ([`Baked`]) and its records: BTF image sets, visibility
//! cube maps, texel volumes and impostors, with their sizes as the format stores them.

use super::*;

/// Everything one bake produces.
#[derive(Clone, Debug, PartialEq)]
pub struct Baked {
    /// Hash of the scene file text + bake settings (computed by the caller).
    pub scene_hash: u64,
    pub settings: BakeSettings,
    pub btf: Vec<BtfImageSet>,
    /// Visibility cube maps.
    pub vcm: Vec<VcmSet>,
    /// Texel volumes, one per species (none when the settings' texel resolution is 0).
    pub texels: Vec<TexelVolume>,
    /// Octahedral impostors, one per species (none when the settings' impostor frames
    /// are 0).
    pub impostors: Vec<Impostor>,
    /// Surfel trees, one per species (none when the settings' surfel budget is 0).
    pub surfels: Vec<SurfelSet>,
}

/// The billboard images of one species at one level.
#[derive(Clone, Debug, PartialEq)]
pub struct BtfImageSet {
    pub species: u32,
    pub level: Level,
    pub views: u32,
    pub lights: u32,
    pub resolution: u32,
    /// Billboard frame: the object's bounding-sphere centre (object frame) and radius; an
    /// image covers a square of side 2*radius centred on the centre, seen from its view
    /// direction.
    pub center: [f32; 3],
    pub radius: f32,
    /// Largest world size of one texel of this level's images (G_max in the thesis' LOD
    /// criterion).
    pub texel_size: f32,
    /// How `direct` and `ambient` hold their images.
    pub encoding: ImageEncoding,
    /// Premultiplied, views*lights images of resolution², view-major: image (v, l) starts
    /// at (v*lights + l) * [`Self::image_bytes`].
    pub direct: Vec<u8>,
    /// Premultiplied, [`AMBIENT_IMAGES_PER_VIEW`] x views images of resolution²: each
    /// view's image under the sky light only, then each view's under the ground's light
    /// only.
    pub ambient: Vec<u8>,
}

/// How a BTF set stores each image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ImageEncoding {
    /// RGBA8 sRGB, level 0 alone (the viewer makes the mips).
    #[default]
    Rgba8,
    /// BC7, the mip chain down to 4 texels a side ([`bc::bc7_chain_bytes`]).
    Bc7,
}

impl ImageEncoding {
    /// The byte that stores it in a record.
    pub fn tag(self) -> u8 {
        match self {
            ImageEncoding::Rgba8 => 0,
            ImageEncoding::Bc7 => 1,
        }
    }

    /// The encoding stored as `tag`, if any.
    pub fn from_tag(tag: u8) -> Option<Self> {
        match tag {
            0 => Some(ImageEncoding::Rgba8),
            1 => Some(ImageEncoding::Bc7),
            _ => None,
        }
    }
}

/// How a VCM set stores its opacity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MapEncoding {
    /// A byte per texel.
    #[default]
    R8,
    /// BC4, each face on its own ([`bc::bc4_bytes`]).
    Bc4,
}

impl MapEncoding {
    /// The byte that stores it in a record.
    pub fn tag(self) -> u8 {
        match self {
            MapEncoding::R8 => 0,
            MapEncoding::Bc4 => 1,
        }
    }

    /// The encoding stored as `tag`, if any.
    pub fn from_tag(tag: u8) -> Option<Self> {
        match tag {
            0 => Some(MapEncoding::R8),
            1 => Some(MapEncoding::Bc4),
            _ => None,
        }
    }
}

/// The visibility cube maps at the 8 bounding-box corners of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct VcmSet {
    pub species: u32,
    /// The object within its level (see the record layout in [`crate::format`]).
    pub owner: u32,
    pub level: Level,
    pub resolution: u32,
    /// How `opacity` holds its faces.
    pub encoding: MapEncoding,
    /// 8 corners x 6 faces of resolution² opacity texels, corner-major then face-major:
    /// a byte each ([`MapEncoding::R8`]), or each face's BC4 blocks.
    pub opacity: Vec<u8>,
    /// Mean opacity of each corner's cube map, in [0, 1].
    pub mean_opacity: [f32; 8],
}

/// One species' whole tree as RGBA volumes in its box (object frame): one per baked light
/// and one lit by the sky.
#[derive(Clone, Debug, PartialEq)]
pub struct TexelVolume {
    pub species: u32,
    /// Light samples (the BTF's direction set of this count).
    pub lights: u32,
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Lowest corner of the volume in the object frame.
    pub box_min: [f32; 3],
    /// Side of one cubic voxel (m).
    pub voxel: f32,
    /// RGBA8 premultiplied, lights+1 volumes (see the record layout in [`crate::format`]).
    pub voxels: Vec<u8>,
}

/// One species' whole tree as an octahedral impostor: a grid of orthographic views of the
/// tree level, unlit colour with coverage and normal with depth, each frame with its own
/// mip chain (see the record layout in [`crate::format`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Impostor {
    pub species: u32,
    pub layout: OctaLayout,
    /// Frames per side.
    pub frames: u32,
    /// Pixels a frame side at level 0.
    pub resolution: u32,
    /// Levels stored, level 0 included.
    pub mip_levels: u32,
    /// Bounding-sphere centre (object frame) and radius: what every frame frames.
    pub center: [f32; 3],
    pub radius: f32,
    /// RGBA8 atlases, level 0 first: sRGB albedo, coverage in alpha.
    pub albedo: Vec<u8>,
    /// RGBA8 atlases as `albedo`: normal * 0.5 + 0.5, depth in alpha.
    pub normal_depth: Vec<u8>,
}

impl BtfImageSet {
    /// Bytes of one image as the set stores it: resolution²*4 (RGBA8) or its BC7 mip
    /// chain; None on overflow or a resolution the format does not allow.
    pub fn image_bytes(&self) -> Option<u64> {
        match self.encoding {
            ImageEncoding::Rgba8 => image_bytes(self.resolution),
            ImageEncoding::Bc7 => BTF_RESOLUTIONS
                .contains(&self.resolution)
                .then(|| bc::bc7_chain_bytes(self.resolution)),
        }
    }

    /// The length `direct` must have: views*lights*[`Self::image_bytes`], or None on
    /// overflow.
    pub fn expected_direct_len(&self) -> Option<u64> {
        self.image_bytes()?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(self.lights))
    }

    /// The length `ambient` must have: 2*views*[`Self::image_bytes`], or None on overflow.
    pub fn expected_ambient_len(&self) -> Option<u64> {
        self.image_bytes()?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(AMBIENT_IMAGES_PER_VIEW))
    }

    /// Every image as stored, direct images first, then the ambient ones (the order the
    /// viewer numbers them in).
    pub fn images(&self) -> impl Iterator<Item = &[u8]> {
        let n = self.image_bytes().unwrap_or(0).max(1) as usize;
        self.direct
            .chunks_exact(n)
            .chain(self.ambient.chunks_exact(n))
    }

    /// The RGBA8 level 0 of one stored image (from [`Self::images`]): itself, or its BC7
    /// level 0 decoded; None when it has not the size of one image.
    pub fn rgba(&self, image: &[u8]) -> Option<std::borrow::Cow<'_, [u8]>> {
        let res = self.resolution;
        match self.encoding {
            ImageEncoding::Rgba8 => (Some(image.len() as u64) == image_bytes(res))
                .then(|| std::borrow::Cow::Owned(image.to_vec())),
            ImageEncoding::Bc7 => {
                let levels = bc::bc7_levels(image, res)?;
                bc::decode_bc7(levels.first()?.1, res, res).map(std::borrow::Cow::Owned)
            }
        }
    }

    /// The ambient images as RGBA8 level 0 (decoded when BC7), None when they do not hold
    /// what the set's fields say.
    pub fn ambient_rgba(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        if self.expected_ambient_len() != Some(self.ambient.len() as u64) {
            return None;
        }
        match self.encoding {
            ImageEncoding::Rgba8 => Some(std::borrow::Cow::Borrowed(&self.ambient)),
            ImageEncoding::Bc7 => {
                let n = self.image_bytes()? as usize;
                let mut out = Vec::with_capacity(
                    self.ambient.len() / n.max(1) * image_bytes(self.resolution)? as usize,
                );
                for image in self.ambient.chunks_exact(n) {
                    out.extend_from_slice(&self.rgba(image)?);
                }
                Some(std::borrow::Cow::Owned(out))
            }
        }
    }
}

impl crate::vcm::billboard::AlphaSet {
    /// A BTF set's sky-lit images as occluders (see
    /// [`AlphaSet::from_sky_lit`](crate::vcm::billboard::AlphaSet::from_sky_lit)), after
    /// checking that its ambient images hold what its fields say. Defined here rather than
    /// in `vcm`, which sits below this file format.
    pub fn new(set: &BtfImageSet) -> crate::Result<Self> {
        let Some(ambient) = set.ambient_rgba() else {
            return Err(crate::Error::BadInput(format!(
                "BTF set of species {} level {:?}: ambient images hold {} bytes, expected {:?}",
                set.species,
                set.level,
                set.ambient.len(),
                set.expected_ambient_len()
            )));
        };
        Self::from_sky_lit(
            set.views,
            set.resolution,
            &ambient,
            glam::Vec3::from(set.center),
            set.radius,
        )
        .map_err(|e| crate::Error::BadInput(format!("BTF set: {e}")))
    }
}

impl VcmSet {
    /// Bytes of one face as stored: resolution² (R8) or its BC4 blocks; None on overflow.
    pub fn face_bytes(&self) -> Option<u64> {
        match self.encoding {
            MapEncoding::R8 => u64::from(self.resolution).checked_mul(u64::from(self.resolution)),
            MapEncoding::Bc4 => {
                let blocks = u64::from(bc::blocks_along(self.resolution));
                blocks
                    .checked_mul(blocks)?
                    .checked_mul(bc::BC4_BLOCK_BYTES as u64)
            }
        }
    }

    /// The length `opacity` must have: 8*6*[`Self::face_bytes`], or None on overflow.
    pub fn expected_opacity_len(&self) -> Option<u64> {
        self.face_bytes()?
            .checked_mul((VCM_CORNERS * CUBE_FACES) as u64)
    }

    /// The opacity a byte per texel (decoded when BC4), None when `opacity` does not hold
    /// what the set's fields say.
    pub fn opacity_r8(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        if self.expected_opacity_len() != Some(self.opacity.len() as u64) {
            return None;
        }
        match self.encoding {
            MapEncoding::R8 => Some(std::borrow::Cow::Borrowed(&self.opacity)),
            MapEncoding::Bc4 => {
                let res = self.resolution;
                let face = self.face_bytes()? as usize;
                let mut out =
                    Vec::with_capacity(VCM_CORNERS * CUBE_FACES * res as usize * res as usize);
                for blocks in self.opacity.chunks_exact(face.max(1)) {
                    out.extend_from_slice(&bc::decode_bc4(blocks, res, res)?);
                }
                Some(std::borrow::Cow::Owned(out))
            }
        }
    }
}

impl TexelVolume {
    /// Voxels in one of its volumes, or None on overflow.
    pub fn voxel_count(&self) -> Option<u64> {
        u64::from(self.dims[0])
            .checked_mul(u64::from(self.dims[1]))?
            .checked_mul(u64::from(self.dims[2]))
    }

    /// The length `voxels` must have: (lights+1)*x*y*z*4, or None on overflow.
    pub fn expected_voxels_len(&self) -> Option<u64> {
        self.voxel_count()?
            .checked_mul(4)?
            .checked_mul(u64::from(self.lights).checked_add(1)?)
    }

    /// The volume's highest corner in the object frame.
    pub fn box_max(&self) -> [f32; 3] {
        std::array::from_fn(|i| self.box_min[i] + self.dims[i] as f32 * self.voxel)
    }
}

impl Impostor {
    /// The bytes of one atlas (`albedo` or `normal_depth`) of these sizes, every level
    /// included, or None on overflow.
    pub fn atlas_bytes(frames: u32, resolution: u32, mip_levels: u32) -> Option<u64> {
        let mut sum: u64 = 0;
        for m in 0..mip_levels.min(32) {
            let side = u64::from(frames).checked_mul(u64::from(resolution >> m))?;
            sum = sum.checked_add(side.checked_mul(side)?.checked_mul(4)?)?;
        }
        Some(sum)
    }

    /// The length `albedo` (and `normal_depth`) must have, or None on overflow.
    pub fn expected_atlas_len(&self) -> Option<u64> {
        Self::atlas_bytes(self.frames, self.resolution, self.mip_levels)
    }

    /// Byte offset and side (pixels) of level `m` in an atlas, if the record has it.
    pub fn level(&self, m: u32) -> Option<(usize, u32)> {
        if m >= self.mip_levels {
            return None;
        }
        let at = Self::atlas_bytes(self.frames, self.resolution, m)?;
        Some((
            usize::try_from(at).ok()?,
            self.frames * (self.resolution >> m),
        ))
    }
}

/// Levels of an impostor's mip chain for frames of `resolution` pixels: down to frames of
/// [`IMPOSTOR_MIN_MIP_SIDE`] pixels (1 for smaller frames).
pub fn impostor_mip_levels(resolution: u32) -> u32 {
    let min = IMPOSTOR_MIN_MIP_SIDE.max(1);
    let mut levels = 1;
    while (resolution >> levels) >= min {
        levels += 1;
    }
    levels
}

impl Baked {
    /// A bake of `scene_hash` with `settings` that holds nothing yet.
    pub fn empty(scene_hash: u64, settings: BakeSettings) -> Baked {
        Baked {
            scene_hash,
            settings,
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
            impostors: Vec::new(),
            surfels: Vec::new(),
        }
    }

    /// Bytes of BTF image data (direct + ambient) over all sets.
    pub fn btf_bytes(&self) -> u64 {
        self.btf
            .iter()
            .map(|s| s.direct.len() as u64 + s.ambient.len() as u64)
            .sum()
    }

    /// Bytes of VCM opacity data over all sets.
    pub fn vcm_bytes(&self) -> u64 {
        self.vcm.iter().map(|s| s.opacity.len() as u64).sum()
    }

    /// Bytes of texel voxels over all volumes.
    pub fn texel_bytes(&self) -> u64 {
        self.texels.iter().map(|t| t.voxels.len() as u64).sum()
    }

    /// Bytes of impostor atlases (both maps, every level) over all impostors.
    pub fn impostor_bytes(&self) -> u64 {
        self.impostors
            .iter()
            .map(|i| i.albedo.len() as u64 + i.normal_depth.len() as u64)
            .sum()
    }

    /// Bytes of surfel tree records over all trees.
    pub fn surfel_bytes(&self) -> u64 {
        self.surfels.iter().map(SurfelSet::record_bytes).sum()
    }
}

fn image_bytes(resolution: u32) -> Option<u64> {
    u64::from(resolution)
        .checked_mul(u64::from(resolution))?
        .checked_mul(4)
}
