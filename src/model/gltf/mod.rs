//! glTF 2.0 import: a user's tree (`.gltf` with its buffers and images, or `.glb`) read into
//! one mesh in the tree frame (metres, +Y up, origin where the author put it) with texture
//! coordinates and one material per triangle, and the materials (base colour factor and
//! texture, alpha mode and cut-off, double-sided).
//!
//! Every mesh of the default scene is read with its node transforms (instancing, several
//! primitives). What is not drawn (animation, skins, morph targets, cameras, lights, other
//! textures) is reported as one warning line each, never silently. Bad input is refused with
//! an error naming the file and the node, mesh, material or image, never a panic: buffers and
//! images are read here (not by the `gltf` crate's importer) so that every allocation is
//! bounded by the sizes of the files, and every accessor is bounds-checked before it is read.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::mesh::Mesh;

pub mod embedded;
pub mod export;
pub mod levels;
mod read;
use read::{load_buffers, percent_decode, read_file, read_image, read_primitive};

/// Most triangles one imported tree may have (every instance of every mesh counted).
pub const MAX_TRIANGLES: u64 = 2_000_000;
/// Most vertices one imported tree may have (every instance counted): with the triangle
/// budget, what bounds the memory an import takes whatever the node hierarchy instances.
pub const MAX_VERTICES: u64 = 2_000_000;
/// Largest coordinate allowed after the node transforms and `scale` (metres): a tree, not a
/// continent.
pub const MAX_COORDINATE_M: f32 = 10_000.0;
/// Largest side of a texture (pixels).
pub const MAX_IMAGE_SIDE: u32 = 8192;
/// Largest file read (the `.gltf`/`.glb`, each buffer and each image file).
pub const MAX_FILE_BYTES: u64 = 1 << 30;
/// The cut-off a `BLEND` material is drawn at: canopy draws every material alpha-tested.
pub const BLEND_CUTOFF: f32 = 0.5;
/// Deepest node hierarchy followed, and most node visits (instancing included).
const MAX_NODE_DEPTH: usize = 64;
const MAX_NODE_VISITS: usize = 100_000;

/// Which axis of the file points up.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +Y (the glTF convention).
    #[default]
    Y,
    /// +Z (some CAD and photogrammetry exports): turned so that +Z becomes +Y.
    Z,
}

/// How a file is placed in the tree frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportOptions {
    /// Uniform scale applied after the file's own transforms.
    pub scale: f32,
    /// The file's up axis.
    pub up: UpAxis,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            scale: 1.0,
            up: UpAxis::Y,
        }
    }
}

/// A material's alpha mode as the file gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlphaMode {
    /// Alpha ignored.
    Opaque,
    /// Alpha-tested at the material's cut-off.
    Mask,
    /// Meant to be blended: drawn alpha-tested at [`BLEND_CUTOFF`].
    Blend,
}

impl AlphaMode {
    /// The name glTF gives it.
    pub fn name(self) -> &'static str {
        match self {
            AlphaMode::Opaque => "OPAQUE",
            AlphaMode::Mask => "MASK",
            AlphaMode::Blend => "BLEND",
        }
    }
}

/// A decoded texture: `width * height` RGBA8 pixels, rows top first, colour sRGB-encoded.
#[derive(Clone, PartialEq)]
pub struct Rgba8Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl std::fmt::Debug for Rgba8Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Rgba8Image({}x{})", self.width, self.height)
    }
}

/// One material of an imported tree.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// The file's name for it (or `material N`).
    pub name: String,
    /// Base colour factor (linear RGBA); also in the vertex colours of its triangles.
    pub base_color: [f32; 4],
    /// The base-colour texture, if any (shared: the bake clones the tree per level).
    pub texture: Option<Arc<Rgba8Image>>,
    /// As the file gives it.
    pub alpha_mode: AlphaMode,
    /// The alpha below which a fragment is discarded: the file's cut-off for `MASK`,
    /// [`BLEND_CUTOFF`] for `BLEND`, 0 for `OPAQUE` (nothing discarded).
    pub alpha_cutoff: f32,
    /// Drawn without back-face culling.
    pub double_sided: bool,
    /// Leaf or needle cards: alpha-tested and its texture actually cuts texels away.
    pub cards: bool,
    /// Lit as foliage (two-sided normals, some light through from behind, the tree's
    /// tint): cards, or a material `canopy export` marked so
    /// (`"extras": {"canopy": {"foliage": true}}`).
    pub foliage: bool,
}

/// A tree read from a glTF file.
#[derive(Clone, Debug)]
pub struct ImportedTree {
    /// Every triangle in the tree frame, sorted by material (see `surfaces`).
    pub mesh: Mesh,
    /// The material of each triangle of `mesh`.
    pub triangle_materials: Vec<u32>,
    /// The materials, indexed by `triangle_materials`.
    pub materials: Vec<Material>,
    /// What was read but is not drawn, one line each.
    pub warnings: Vec<String>,
    /// Its twig and main-branch levels as the file gives them, or why it gives none
    /// ([`levels::find`]).
    pub levels: Result<levels::ImportedLevels, String>,
}

impl ImportedTree {
    /// Triangles of each material, in material order.
    pub fn triangles_per_material(&self) -> Vec<usize> {
        let mut n = vec![0usize; self.materials.len()];
        for &m in &self.triangle_materials {
            if let Some(c) = n.get_mut(m as usize) {
                *c += 1;
            }
        }
        n
    }
}

/// A glTF file that cannot be used: the file and what is wrong, naming the node, mesh,
/// material or image.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", file.display())]
pub struct GltfError {
    pub file: PathBuf,
    pub message: String,
}

type Res<T> = Result<T, String>;

/// Reads the tree of the glTF file at `path` (`.gltf` or `.glb`).
pub fn import(path: &Path, options: ImportOptions) -> Result<ImportedTree, GltfError> {
    let fail = |message: String| GltfError {
        file: path.to_path_buf(),
        message,
    };
    let bytes = match embedded::lookup(path) {
        Some(b) => b.to_vec(),
        None => {
            let size = std::fs::metadata(path)
                .map_err(|e| fail(format!("cannot read it: {e}")))?
                .len();
            if size > MAX_FILE_BYTES {
                return Err(fail(format!(
                    "it is {size} bytes; canopy reads files up to {MAX_FILE_BYTES} bytes"
                )));
            }
            std::fs::read(path).map_err(|e| fail(format!("cannot read it: {e}")))?
        }
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    import_slice(&bytes, dir, options).map_err(fail)
}

/// The bytes of one of a glTF tree's files ([`files_of`]), embedded or on disk, refused
/// over the reader's size limit.
pub fn file_bytes(path: &Path) -> Result<Vec<u8>, String> {
    read_file(path)
}

/// The files a glTF tree is made of: the file itself, then the local buffers and images its
/// JSON names (for the bake cache's key). Unreadable or unparsable files give what is known.
pub fn files_of(path: &Path) -> Vec<PathBuf> {
    let mut out = vec![path.to_path_buf()];
    let Ok(bytes) = read_file(path) else {
        return out;
    };
    let Ok((json, _)) = read::split_glb(&bytes) else {
        return out;
    };
    let Ok(parsed) = ::gltf::Gltf::from_slice_without_validation(json) else {
        return out;
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let root = parsed.document.as_json();
    let uris = root
        .buffers
        .iter()
        .filter_map(|b| b.uri.as_deref())
        .chain(root.images.iter().filter_map(|i| i.uri.as_deref()));
    for uri in uris {
        if !uri.starts_with("data:") && !uri.contains("://") {
            out.push(dir.join(percent_decode(uri)));
        }
    }
    out
}

/// Reads a tree from the bytes of a `.gltf` or `.glb` file whose external buffers and images
/// are relative to `dir`. The error names what is wrong, not the file.
pub fn import_slice(bytes: &[u8], dir: &Path, options: ImportOptions) -> Res<ImportedTree> {
    if !options.scale.is_finite() || options.scale <= 0.0 {
        return Err(format!("scale must be > 0, found {}", options.scale));
    }
    // A GLB is split here (gltf 1.4 underflows on a header length under 12), its JSON
    // chunk parsed as a `.gltf`.
    let (json, blob) = read::split_glb(bytes)?;
    let parsed = ::gltf::Gltf::from_slice_without_validation(json)
        .map_err(|e| format!("not a glTF 2.0 file: {e}"))?;
    check_required_extensions(&parsed.document)?;
    check_position_indices(parsed.document.as_json())?;
    let blob = blob.map(<[u8]>::to_vec);
    let doc = ::gltf::Document::from_json(parsed.document.into_json())
        .map_err(|e| format!("invalid glTF: {e}"))?;
    let warnings = ignored_features(&doc);

    let buffers = load_buffers(&doc, blob, dir)?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| "the file has no scene".to_string())?;

    // The file's frame (scale, up axis) turned into the tree frame.
    let frame = Mat4::from_scale(Vec3::splat(options.scale))
        * match options.up {
            UpAxis::Y => Mat4::IDENTITY,
            UpAxis::Z => Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        };
    let (instances, placements) = mesh_instances(&scene, frame)?;

    let mut reader = TreeReader {
        doc: &doc,
        buffers: &buffers,
        dir,
        materials: Vec::new(),
        material_of: std::collections::HashMap::new(),
        images: Default::default(),
        meshes: Default::default(),
        per_material: Vec::new(),
        triangles: 0,
        vertices: 0,
        warnings,
    };
    for (node, mesh, transform, _) in &instances {
        reader.place(node, mesh, *transform)?;
    }
    let TreeReader {
        materials,
        meshes,
        per_material,
        triangles,
        warnings,
        ..
    } = reader;
    if triangles == 0 {
        return Err("the default scene has no triangles".into());
    }
    // The mesh's triangles in its own frame, by material.
    let local = |mesh: usize| {
        let mut out = vec![Mesh::default(); materials.len()];
        for (m, part) in meshes.get(&mesh).into_iter().flatten() {
            out[*m].append(part, Mat4::IDENTITY);
        }
        out
    };
    let levels = levels::find(&placements, &local, &materials);
    // One mesh, sorted by material; foliage flagged.
    let whole = levels::Part::combine(&per_material, &materials);
    Ok(ImportedTree {
        mesh: whole.mesh,
        triangle_materials: whole.triangle_materials,
        materials,
        warnings,
        levels,
    })
}

/// A node instance that draws a mesh: the node, its mesh, its transform in the tree frame
/// and the nearest ancestor instance that draws one.
type Instance<'a> = (::gltf::Node<'a>, ::gltf::Mesh<'a>, Mat4, Option<usize>);

/// Which node instances of `scene` draw which mesh, in file order of their nodes, and their
/// placements; `frame` turns the file's frame into the tree frame.
fn mesh_instances<'a>(
    scene: &::gltf::Scene<'a>,
    frame: Mat4,
) -> Res<(Vec<Instance<'a>>, Vec<levels::Placement>)> {
    // Which node instances draw which mesh, with their transforms in the tree frame and the
    // nearest ancestor instance that draws one.
    let mut found: Vec<Instance<'a>> = Vec::new();
    let mut stack: Vec<(::gltf::Node<'_>, Mat4, usize, Option<usize>)> =
        scene.nodes().map(|n| (n, frame, 0, None)).collect();
    let mut visits = 0usize;
    while let Some((node, parent, depth, holder)) = stack.pop() {
        visits += 1;
        if visits > MAX_NODE_VISITS {
            return Err(format!(
                "the node hierarchy has over {MAX_NODE_VISITS} node instances; canopy reads at most that many"
            ));
        }
        if depth > MAX_NODE_DEPTH {
            return Err(format!(
                "{} is nested over {MAX_NODE_DEPTH} levels deep (a cycle in `children`?)",
                node_name(&node)
            ));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        if !local.is_finite() {
            return Err(format!(
                "{} has a transform that is not finite",
                node_name(&node)
            ));
        }
        let world = parent * local;
        let mut holder = holder;
        if let Some(mesh) = node.mesh() {
            found.push((node.clone(), mesh, world, holder));
            holder = Some(found.len() - 1);
        }
        for child in node.children() {
            stack.push((child, world, depth + 1, holder));
        }
    }
    // Instances in file order of their nodes, so that the result does not depend on the
    // traversal.
    let mut order: Vec<usize> = (0..found.len()).collect();
    order.sort_by_key(|&i| found[i].0.index());
    let mut rank = vec![0usize; found.len()];
    for (r, &i) in order.iter().enumerate() {
        rank[i] = r;
    }
    let instances: Vec<_> = order.iter().map(|&i| found[i].clone()).collect();
    let placements: Vec<levels::Placement> = instances
        .iter()
        .map(|(node, mesh, world, holder)| levels::Placement {
            mesh: mesh.index(),
            mesh_name: mesh_name(mesh),
            node_name: node_name(node),
            world: *world,
            parent: holder.map(|h| rank[h]),
        })
        .collect();
    Ok((instances, placements))
}

/// A tree's meshes and materials while its node instances are read.
struct TreeReader<'a> {
    doc: &'a ::gltf::Document,
    buffers: &'a [Vec<u8>],
    dir: &'a Path,
    materials: Vec<Material>,
    /// Index in `materials` of each of the file's materials read.
    material_of: std::collections::HashMap<Option<usize>, usize>,
    images: std::collections::HashMap<usize, Arc<Rgba8Image>>,
    /// Each mesh read once: its primitives in its own frame, with their materials.
    meshes: std::collections::HashMap<usize, Vec<(usize, Mesh)>>,
    /// Every instance's triangles in the tree frame, by material.
    per_material: Vec<Mesh>,
    triangles: u64,
    vertices: u64,
    warnings: Vec<String>,
}

impl TreeReader<'_> {
    /// Appends the instance of `mesh` at `node`, placed by `transform`, to the tree (the
    /// mesh read on its first instance), refusing a tree over the size limits.
    fn place(
        &mut self,
        node: &::gltf::Node<'_>,
        mesh: &::gltf::Mesh<'_>,
        transform: Mat4,
    ) -> Res<()> {
        if !self.meshes.contains_key(&mesh.index()) {
            let parts = self.read_mesh(node, mesh)?;
            self.meshes.insert(mesh.index(), parts);
        }
        for (p, (m, part)) in self.meshes[&mesh.index()].iter().enumerate() {
            let at = format!("{} mesh {} primitive {p}", node_name(node), mesh_name(mesh));
            self.triangles += part.triangle_count() as u64;
            self.vertices += part.vertices.len() as u64;
            if self.vertices > MAX_VERTICES {
                return Err(format!(
                    "the tree has over {MAX_VERTICES} vertices (at {at}); canopy imports at most \
                     {MAX_VERTICES}: decimate it (Blender: Decimate modifier) or use a lower LOD"
                ));
            }
            if self.triangles > MAX_TRIANGLES {
                return Err(format!(
                    "the tree has over {MAX_TRIANGLES} triangles (at {at}); canopy imports at most \
                     {MAX_TRIANGLES}: decimate it (Blender: Decimate modifier) or use a lower LOD"
                ));
            }
            let target = &mut self.per_material[*m];
            let first = target.vertices.len();
            target.append(part, transform);
            for v in &target.vertices[first..] {
                let p = Vec3::from(v.position);
                if !p.is_finite() {
                    return Err(format!(
                        "{at}: a vertex position is not finite (NaN or inf)"
                    ));
                }
                if p.abs().max_element() > MAX_COORDINATE_M {
                    return Err(format!(
                        "{at}: a vertex lies {:.0} m from the origin; canopy takes coordinates \
                         within {MAX_COORDINATE_M} m (is the file in millimetres? set `scale`)",
                        p.abs().max_element()
                    ));
                }
            }
        }
        Ok(())
    }

    /// The primitives of `mesh` (first met at `node`) in its own frame, with their
    /// materials (read on first use).
    fn read_mesh(
        &mut self,
        node: &::gltf::Node<'_>,
        mesh: &::gltf::Mesh<'_>,
    ) -> Res<Vec<(usize, Mesh)>> {
        let mut parts = Vec::new();
        for prim in mesh.primitives() {
            let at = format!(
                "{} mesh {} primitive {}",
                node_name(node),
                mesh_name(mesh),
                prim.index()
            );
            let key = prim.material().index();
            let m = match self.material_of.get(&key) {
                Some(&m) => m,
                None => {
                    let mat = read_material(
                        self.doc,
                        &prim.material(),
                        self.buffers,
                        self.dir,
                        &mut self.images,
                    )?;
                    self.materials.push(mat);
                    self.per_material.push(Mesh::default());
                    self.material_of.insert(key, self.materials.len() - 1);
                    self.materials.len() - 1
                }
            };
            let uv_set = prim
                .material()
                .pbr_metallic_roughness()
                .base_color_texture()
                .map(|info| {
                    info.texture_transform()
                        .and_then(|t| t.tex_coord())
                        .unwrap_or(info.tex_coord())
                })
                .unwrap_or(0);
            let mut part = read_primitive(&prim, self.buffers, uv_set, &at, &mut self.warnings)?;
            let part_transform = transform_uv(&prim.material());
            let base = Vec3::from_slice(&self.materials[m].base_color[..3]);
            for v in &mut part.vertices {
                v.color = (Vec3::from(v.color) * base).to_array();
                v.uv = part_transform(Vec2::from(v.uv)).to_array();
            }
            parts.push((m, part));
        }
        Ok(parts)
    }
}

fn node_name(node: &::gltf::Node<'_>) -> String {
    match node.name() {
        Some(n) => format!("node {} `{n}`", node.index()),
        None => format!("node {}", node.index()),
    }
}

fn mesh_name(mesh: &::gltf::Mesh<'_>) -> String {
    match mesh.name() {
        Some(n) => format!("{} `{n}`", mesh.index()),
        None => mesh.index().to_string(),
    }
}

fn material_name(m: &::gltf::Material<'_>) -> String {
    match (m.index(), m.name()) {
        (Some(i), Some(n)) => format!("material {i} `{n}`"),
        (Some(i), None) => format!("material {i}"),
        (None, _) => "the default material".into(),
    }
}

/// Refuses a POSITION that names no accessor: gltf-json 1.4's validation reads that
/// accessor unchecked (and would panic).
fn check_position_indices(root: &::gltf::json::Root) -> Res<()> {
    use ::gltf::json::validation::Checked;
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let position = prim
                .attributes
                .get(&Checked::Valid(::gltf::Semantic::Positions));
            if let Some(i) = position
                && i.value() >= root.accessors.len()
            {
                return Err(format!(
                    "mesh {m} primitive {p}: POSITION names accessor {}, but the file has {}",
                    i.value(),
                    root.accessors.len()
                ));
            }
        }
    }
    Ok(())
}

/// Refuses the required extensions canopy cannot read, saying what to do instead.
fn check_required_extensions(doc: &::gltf::Document) -> Res<()> {
    const READ: &[&str] = &["KHR_texture_transform"];
    for ext in doc.extensions_required() {
        if READ.contains(&ext) {
            continue;
        }
        let advice = match ext {
            "KHR_draco_mesh_compression" => {
                "Draco-compressed meshes are not supported: re-export without compression \
                 (Blender: File > Export > glTF 2.0, Data > Compression off)"
            }
            "EXT_meshopt_compression" => {
                "meshopt-compressed buffers are not supported: re-export without compression \
                 (gltfpack without -c, or Blender's exporter)"
            }
            "KHR_texture_basisu" => {
                "KTX2/Basis Universal textures are not supported: re-export with PNG or JPEG \
                 textures (Blender: Images > Automatic)"
            }
            "EXT_texture_webp" => {
                "WebP textures are not supported: re-export with PNG or JPEG textures \
                 (Blender: Images > Automatic)"
            }
            "KHR_mesh_quantization" => {
                "quantized vertex attributes are not supported: re-export without \
                 quantization (gltfpack -noq)"
            }
            _ => "canopy does not support it: re-export without it",
        };
        return Err(format!("the file requires extension `{ext}`; {advice}"));
    }
    Ok(())
}

/// One warning line per feature present but not drawn.
fn ignored_features(doc: &::gltf::Document) -> Vec<String> {
    let mut w = Vec::new();
    let mut note = |n: usize, what: &str| {
        if n > 0 {
            w.push(format!("ignored: {n} {what}"));
        }
    };
    note(doc.animations().count(), "animation(s)");
    note(doc.skins().count(), "skin(s) (drawn in their bind pose)");
    note(
        doc.meshes()
            .filter(|m| m.primitives().any(|p| p.morph_targets().next().is_some()))
            .count(),
        "mesh(es) with morph targets (drawn without them)",
    );
    note(doc.cameras().count(), "camera(s)");
    let handled = ["KHR_texture_transform"];
    for ext in doc.extensions_used() {
        if ext == "KHR_lights_punctual" {
            w.push("ignored: lights (KHR_lights_punctual); canopy lights the tree itself".into());
        } else if !handled.contains(&ext) {
            w.push(format!("ignored: extension `{ext}`"));
        }
    }
    if doc
        .materials()
        .any(|m| m.normal_texture().is_some() || m.occlusion_texture().is_some())
    {
        w.push("ignored: normal and occlusion textures (only the base colour is drawn)".into());
    }
    if doc.materials().any(|m| {
        m.emissive_texture().is_some()
            || m.pbr_metallic_roughness()
                .metallic_roughness_texture()
                .is_some()
    }) {
        w.push("ignored: emissive and metallic-roughness textures".into());
    }
    w
}

/// The material's KHR_texture_transform as a function of the texture coordinates.
fn transform_uv(material: &::gltf::Material<'_>) -> impl Fn(Vec2) -> Vec2 + use<> {
    let t = material
        .pbr_metallic_roughness()
        .base_color_texture()
        .and_then(|i| i.texture_transform())
        .map(|t| (Vec2::from(t.offset()), t.rotation(), Vec2::from(t.scale())));
    move |uv: Vec2| match t {
        Some((offset, rotation, scale)) => texture_transform(uv, offset, rotation, scale),
        None => uv,
    }
}

/// KHR_texture_transform: `uv` scaled, then turned `rotation` radians counter-clockwise
/// (in the image, whose v runs down: clockwise as seen), then offset.
fn texture_transform(uv: Vec2, offset: Vec2, rotation: f32, scale: Vec2) -> Vec2 {
    let s = uv * scale;
    let (sin, cos) = rotation.sin_cos();
    Vec2::new(cos * s.x + sin * s.y, -sin * s.x + cos * s.y) + offset
}

/// A material with its base-colour texture decoded (each image once).
fn read_material(
    doc: &::gltf::Document,
    m: &::gltf::Material<'_>,
    buffers: &[Vec<u8>],
    dir: &Path,
    images: &mut std::collections::HashMap<usize, Arc<Rgba8Image>>,
) -> Res<Material> {
    let pbr = m.pbr_metallic_roughness();
    let base_color = pbr.base_color_factor();
    let name = material_name(m);
    if base_color.iter().any(|c| !c.is_finite()) {
        return Err(format!("{name}: baseColorFactor is not finite"));
    }
    let texture = match pbr.base_color_texture() {
        Some(info) => {
            let image = info.texture().source();
            let i = image.index();
            Some(match images.get(&i) {
                Some(img) => img.clone(),
                None => {
                    let img = Arc::new(
                        read_image(doc, &image, buffers, dir)
                            .map_err(|e| format!("{name}: {e}"))?,
                    );
                    images.insert(i, img.clone());
                    img
                }
            })
        }
        None => None,
    };
    let alpha_mode = match m.alpha_mode() {
        ::gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
        ::gltf::material::AlphaMode::Mask => AlphaMode::Mask,
        ::gltf::material::AlphaMode::Blend => AlphaMode::Blend,
    };
    let alpha_cutoff = match alpha_mode {
        AlphaMode::Opaque => 0.0,
        AlphaMode::Mask => m.alpha_cutoff().unwrap_or(0.5),
        AlphaMode::Blend => BLEND_CUTOFF,
    };
    if !alpha_cutoff.is_finite() {
        return Err(format!("{name}: alphaCutoff is not finite"));
    }
    let cards = alpha_mode != AlphaMode::Opaque
        && texture.as_ref().is_some_and(|t| {
            t.pixels
                .chunks_exact(4)
                .any(|p| f32::from(p[3]) / 255.0 * base_color[3] < alpha_cutoff)
        });
    Ok(Material {
        name: m.name().map_or_else(|| name.clone(), str::to_owned),
        base_color,
        texture,
        alpha_mode,
        alpha_cutoff,
        double_sided: m.double_sided(),
        cards,
        foliage: cards || marked_foliage(m.extras()),
    })
}

/// The material's extras say `canopy export` wrote it as foliage.
fn marked_foliage(extras: &::gltf::json::Extras) -> bool {
    extras
        .as_ref()
        .and_then(|raw| serde_json::from_str::<serde_json::Value>(raw.get()).ok())
        .and_then(|v| {
            v.pointer("/canopy/foliage")
                .and_then(serde_json::Value::as_bool)
        })
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_transform_follows_the_extensions_example() {
        // The extension's example: the lower left quadrant of the image, rotated clockwise
        // 90 degrees.
        let t = |u, v| {
            texture_transform(
                Vec2::new(u, v),
                Vec2::new(0.0, 1.0),
                std::f32::consts::FRAC_PI_2,
                Vec2::splat(0.5),
            )
        };
        let close = |a: Vec2, b: Vec2| (a - b).length() < 1e-6;
        assert!(close(t(0.0, 0.0), Vec2::new(0.0, 1.0)));
        assert!(close(t(1.0, 0.0), Vec2::new(0.0, 0.5)));
        assert!(close(t(0.0, 1.0), Vec2::new(0.5, 1.0)));
        assert!(close(t(1.0, 1.0), Vec2::new(0.5, 0.5)));
    }
}
