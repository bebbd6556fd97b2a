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

use super::mesh::{Mesh, Vertex};

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
    /// Leaf or needle cards: alpha-tested and its texture actually cuts texels away. Drawn
    /// lit as foliage (two-sided normals, some light through from behind, the tree's tint).
    pub cards: bool,
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
    let bytes = read_file(path).map_err(fail)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    import_slice(&bytes, dir, options).map_err(fail)
}

/// The files a glTF tree is made of: the file itself, then the local buffers and images its
/// JSON names (for the bake cache's key). Unreadable or unparsable files give what is known.
pub fn files_of(path: &Path) -> Vec<PathBuf> {
    let mut out = vec![path.to_path_buf()];
    let Ok(bytes) = read_file(path) else {
        return out;
    };
    let Ok(parsed) = ::gltf::Gltf::from_slice_without_validation(&bytes) else {
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
    let parsed = ::gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| format!("not a glTF 2.0 file: {e}"))?;
    check_required_extensions(&parsed.document)?;
    let blob = parsed.blob;
    let doc = ::gltf::Document::from_json(parsed.document.into_json())
        .map_err(|e| format!("invalid glTF: {e}"))?;
    let mut warnings = ignored_features(&doc);

    let buffers = load_buffers(&doc, blob, dir)?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| "the file has no scene".to_string())?;

    // Which node instances draw which mesh, with their transforms in the tree frame.
    let frame = Mat4::from_scale(Vec3::splat(options.scale))
        * match options.up {
            UpAxis::Y => Mat4::IDENTITY,
            UpAxis::Z => Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        };
    let mut instances: Vec<(::gltf::Node<'_>, ::gltf::Mesh<'_>, Mat4)> = Vec::new();
    let mut stack: Vec<(::gltf::Node<'_>, Mat4, usize)> =
        scene.nodes().map(|n| (n, frame, 0)).collect();
    let mut visits = 0usize;
    while let Some((node, parent, depth)) = stack.pop() {
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
        if let Some(mesh) = node.mesh() {
            instances.push((node.clone(), mesh, world));
        }
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
    }
    // Instances in file order of their nodes, so that the result does not depend on the
    // traversal.
    instances.sort_by_key(|(n, _, _)| n.index());

    let mut materials = Vec::new();
    let mut material_of = std::collections::HashMap::new();
    let mut per_material: Vec<Mesh> = Vec::new();
    let mut triangles = 0u64;
    let mut vertices = 0u64;
    let mut images: std::collections::HashMap<usize, Arc<Rgba8Image>> = Default::default();
    for (node, mesh, transform) in &instances {
        for prim in mesh.primitives() {
            let at = format!(
                "{} mesh {} primitive {}",
                node_name(node),
                mesh_name(mesh),
                prim.index()
            );
            let key = prim.material().index();
            let m = match material_of.get(&key) {
                Some(&m) => m,
                None => {
                    let mat = read_material(&prim.material(), &buffers, dir, &mut images)?;
                    materials.push(mat);
                    per_material.push(Mesh::default());
                    material_of.insert(key, materials.len() - 1);
                    materials.len() - 1
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
            let part = read_primitive(&prim, &buffers, uv_set, &at, &mut warnings)?;
            let part_transform = transform_uv(&prim.material());
            triangles += part.triangle_count() as u64;
            vertices += part.vertices.len() as u64;
            if vertices > MAX_VERTICES {
                return Err(format!(
                    "the tree has over {MAX_VERTICES} vertices (at {at}); canopy imports at most \
                     {MAX_VERTICES}: decimate it (Blender: Decimate modifier) or use a lower LOD"
                ));
            }
            if triangles > MAX_TRIANGLES {
                return Err(format!(
                    "the tree has over {MAX_TRIANGLES} triangles (at {at}); canopy imports at most \
                     {MAX_TRIANGLES}: decimate it (Blender: Decimate modifier) or use a lower LOD"
                ));
            }
            let base = Vec3::from_slice(&materials[m].base_color[..3]);
            let mut placed = part;
            for v in &mut placed.vertices {
                v.color = (Vec3::from(v.color) * base).to_array();
                v.uv = part_transform(Vec2::from(v.uv)).to_array();
            }
            let target = &mut per_material[m];
            let first = target.vertices.len();
            target.append(&placed, *transform);
            for v in &target.vertices[first..] {
                let p = Vec3::from(v.position);
                if !p.is_finite() {
                    return Err(format!("{at}: a vertex position is not finite (NaN or inf)"));
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
    }
    if triangles == 0 {
        return Err("the default scene has no triangles".into());
    }
    // One mesh, sorted by material; cards flagged as foliage.
    let mut out = Mesh::default();
    let mut triangle_materials = Vec::with_capacity(triangles as usize);
    for (m, part) in per_material.iter().enumerate() {
        let foliage = if materials[m].cards { 1.0 } else { 0.0 };
        let first = out.vertices.len();
        out.append(part, Mat4::IDENTITY);
        for v in &mut out.vertices[first..] {
            v.foliage = foliage;
        }
        triangle_materials.extend(std::iter::repeat_n(m as u32, part.triangle_count()));
    }
    Ok(ImportedTree {
        mesh: out,
        triangle_materials,
        materials,
        warnings,
    })
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

/// Refuses the required extensions canopy cannot read, saying what to do instead.
fn check_required_extensions(doc: &::gltf::Document) -> Res<()> {
    const READ: &[&str] = &["KHR_texture_transform", "KHR_materials_unlit"];
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
    let handled = ["KHR_texture_transform", "KHR_materials_unlit"];
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

/// Reads a whole file, refusing one over [`MAX_FILE_BYTES`] before reading it.
fn read_file(path: &Path) -> Res<Vec<u8>> {
    let size = std::fs::metadata(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?
        .len();
    if size > MAX_FILE_BYTES {
        return Err(format!(
            "{} is {size} bytes; canopy reads files up to {MAX_FILE_BYTES} bytes",
            path.display()
        ));
    }
    std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// The bytes a URI names: a `data:` URI (base64) or a path relative to `dir`.
fn read_uri(uri: &str, dir: &Path) -> Res<Vec<u8>> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let Some((_, data)) = rest.split_once(";base64,") else {
            return Err("a data URI that is not base64".into());
        };
        return base64_decode(data).ok_or_else(|| "a data URI with invalid base64".into());
    }
    if uri.contains("://") {
        return Err(format!(
            "URI `{uri}` is not a local file; canopy reads files next to the glTF only"
        ));
    }
    let decoded = percent_decode(uri);
    let rel = Path::new(&decoded);
    if rel.is_absolute() {
        return Err(format!("URI `{uri}` is an absolute path; use a relative one"));
    }
    read_file(&dir.join(rel))
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = b
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (b[i], hex) {
            (b'%', Some(v)) => {
                out.push(v);
                i += 3;
            }
            (c, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let mut acc = 0u32;
    let mut bits = 0;
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' | b'\n' | b'\r' | b' ' => continue,
            _ => return None,
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    Some(out)
}

/// Every buffer's bytes, each at least as long as its declared `byteLength`.
fn load_buffers(doc: &::gltf::Document, blob: Option<Vec<u8>>, dir: &Path) -> Res<Vec<Vec<u8>>> {
    let mut blob = blob;
    let mut out = Vec::new();
    for b in doc.buffers() {
        let data = match b.source() {
            ::gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                format!("buffer {} refers to the GLB binary chunk, which is missing", b.index())
            })?,
            ::gltf::buffer::Source::Uri(uri) => {
                read_uri(uri, dir).map_err(|e| format!("buffer {} (`{uri}`): {e}", b.index()))?
            }
        };
        if data.len() < b.length() {
            return Err(format!(
                "buffer {} holds {} bytes but declares byteLength {}",
                b.index(),
                data.len(),
                b.length()
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// One accessor's values as floats, `dims` per element (integers as they are, or in 0..1 /
/// -1..1 when normalized), after checking that it lies inside its view and buffer.
fn read_accessor(acc: &::gltf::Accessor<'_>, buffers: &[Vec<u8>], what: &str) -> Res<(Vec<f32>, usize)> {
    use ::gltf::accessor::DataType;
    let name = format!("{what} accessor {}", acc.index());
    if acc.sparse().is_some() {
        return Err(format!("{name} is sparse; canopy does not read sparse accessors"));
    }
    let view = acc
        .view()
        .ok_or_else(|| format!("{name} has no bufferView"))?;
    let dims = acc.dimensions().multiplicity();
    let comp = acc.data_type().size();
    let elem = dims * comp;
    let stride = view.stride().unwrap_or(elem);
    if stride < elem {
        return Err(format!("{name}: byteStride {stride} is smaller than its element ({elem} bytes)"));
    }
    let count = acc.count();
    if count == 0 {
        return Ok((Vec::new(), dims));
    }
    let out_of_range = || format!("{name} is out of range of its buffer view {} or buffer", view.index());
    let span = (count - 1)
        .checked_mul(stride)
        .and_then(|s| s.checked_add(elem))
        .and_then(|s| s.checked_add(acc.offset()))
        .ok_or_else(out_of_range)?;
    if span > view.length() {
        return Err(out_of_range());
    }
    let buffer = buffers
        .get(view.buffer().index())
        .ok_or_else(out_of_range)?;
    let start = view.offset().checked_add(acc.offset()).ok_or_else(out_of_range)?;
    let end = view
        .offset()
        .checked_add(view.length())
        .ok_or_else(out_of_range)?;
    if end > buffer.len() {
        return Err(out_of_range());
    }
    let bytes = &buffer[start..end];
    let normalized = acc.normalized();
    let mut out = Vec::with_capacity(count * dims);
    for i in 0..count {
        let e = &bytes[i * stride..i * stride + elem];
        for c in e.chunks_exact(comp) {
            let v = match acc.data_type() {
                DataType::F32 => f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                DataType::U8 if normalized => f32::from(c[0]) / 255.0,
                DataType::U8 => f32::from(c[0]),
                DataType::I8 if normalized => (f32::from(c[0] as i8) / 127.0).max(-1.0),
                DataType::I8 => f32::from(c[0] as i8),
                DataType::U16 => {
                    let v = f32::from(u16::from_le_bytes([c[0], c[1]]));
                    if normalized { v / 65535.0 } else { v }
                }
                DataType::I16 => {
                    let v = f32::from(i16::from_le_bytes([c[0], c[1]]));
                    if normalized { (v / 32767.0).max(-1.0) } else { v }
                }
                DataType::U32 => u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32,
            };
            out.push(v);
        }
    }
    Ok((out, dims))
}

/// Indices as u32 (exact, unlike [`read_accessor`]'s floats).
fn read_indices(acc: &::gltf::Accessor<'_>, buffers: &[Vec<u8>], vertices: usize, at: &str) -> Res<Vec<u32>> {
    use ::gltf::accessor::{DataType, Dimensions};
    let name = format!("{at}: indices accessor {}", acc.index());
    if acc.dimensions() != Dimensions::Scalar
        || !matches!(acc.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
        || acc.normalized()
    {
        return Err(format!("{name} must be unsigned integer scalars"));
    }
    // Read through the float path only for its bounds checks; u32 above 2^24 would lose
    // precision there, so decode the bytes again here.
    let (_, _) = read_accessor(acc, buffers, at)?;
    let Some(view) = acc.view() else {
        return Err(format!("{name} has no bufferView"));
    };
    let comp = acc.data_type().size();
    let stride = view.stride().unwrap_or(comp);
    let buffer = &buffers[view.buffer().index()];
    let start = view.offset() + acc.offset();
    let mut out = Vec::with_capacity(acc.count());
    for i in 0..acc.count() {
        let c = &buffer[start + i * stride..start + i * stride + comp];
        let v = match comp {
            1 => u32::from(c[0]),
            2 => u32::from(u16::from_le_bytes([c[0], c[1]])),
            _ => u32::from_le_bytes([c[0], c[1], c[2], c[3]]),
        };
        if v as usize >= vertices {
            return Err(format!("{name}: index {v} is out of range of the {vertices} vertices"));
        }
        out.push(v);
    }
    Ok(out)
}

/// One primitive as a mesh in its mesh's frame: positions, normals (computed, area-weighted,
/// where the file has none), texture coordinates of set `uv_set`, COLOR_0 in the colours.
fn read_primitive(
    prim: &::gltf::Primitive<'_>,
    buffers: &[Vec<u8>],
    uv_set: u32,
    at: &str,
    warnings: &mut Vec<String>,
) -> Res<Mesh> {
    use ::gltf::mesh::Mode;
    use ::gltf::mesh::Semantic;
    let mode = prim.mode();
    if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
        let line = format!("ignored: {at} draws {mode:?}, not triangles");
        if !warnings.contains(&line) {
            warnings.push(line);
        }
        return Ok(Mesh::default());
    }
    let float3 = |semantic: &Semantic, what: &str| -> Res<Option<Vec<f32>>> {
        let Some(acc) = prim.get(semantic) else {
            return Ok(None);
        };
        if acc.dimensions() != ::gltf::accessor::Dimensions::Vec3
            || acc.data_type() != ::gltf::accessor::DataType::F32
        {
            return Err(format!("{at}: {what} must be float VEC3"));
        }
        Ok(Some(read_accessor(&acc, buffers, &format!("{at}: {what}"))?.0))
    };
    let positions = float3(&Semantic::Positions, "POSITION")?
        .ok_or_else(|| format!("{at} has no POSITION"))?;
    let n = positions.len() / 3;
    let normals = float3(&Semantic::Normals, "NORMAL")?;
    if normals.as_ref().is_some_and(|v| v.len() != positions.len()) {
        return Err(format!("{at}: NORMAL and POSITION counts differ"));
    }
    let uvs = match prim.get(&Semantic::TexCoords(uv_set)) {
        Some(acc) => {
            let (v, dims) = read_accessor(&acc, buffers, &format!("{at}: TEXCOORD_{uv_set}"))?;
            if dims != 2 || v.len() / 2 != n {
                return Err(format!("{at}: TEXCOORD_{uv_set} must be VEC2, one per vertex"));
            }
            Some(v)
        }
        None => None,
    };
    let colors = match prim.get(&Semantic::Colors(0)) {
        Some(acc) => {
            let (v, dims) = read_accessor(&acc, buffers, &format!("{at}: COLOR_0"))?;
            if !(dims == 3 || dims == 4) || v.len() / dims != n {
                return Err(format!("{at}: COLOR_0 must be VEC3 or VEC4, one per vertex"));
            }
            Some((v, dims))
        }
        None => None,
    };
    let raw = match prim.indices() {
        Some(acc) => read_indices(&acc, buffers, n, at)?,
        None => (0..n as u32).collect(),
    };
    let indices: Vec<u32> = match mode {
        Mode::Triangles => raw.chunks_exact(3).flatten().copied().collect(),
        Mode::TriangleStrip => (2..raw.len())
            .flat_map(|i| {
                if i % 2 == 0 {
                    [raw[i - 2], raw[i - 1], raw[i]]
                } else {
                    [raw[i - 1], raw[i - 2], raw[i]]
                }
            })
            .collect(),
        _ => (2..raw.len())
            .flat_map(|i| [raw[0], raw[i - 1], raw[i]])
            .collect(),
    };
    let mut mesh = Mesh {
        vertices: (0..n)
            .map(|i| {
                let p = Vec3::from_slice(&positions[3 * i..3 * i + 3]);
                let normal = normals
                    .as_ref()
                    .map_or(Vec3::ZERO, |v| Vec3::from_slice(&v[3 * i..3 * i + 3]));
                let color = colors.as_ref().map_or(Vec3::ONE, |(v, d)| {
                    Vec3::from_slice(&v[d * i..d * i + 3])
                });
                let mut vx = Vertex::new(p, normal.normalize_or_zero(), color, 0.0);
                if let Some(uv) = &uvs {
                    vx.uv = [uv[2 * i], uv[2 * i + 1]];
                }
                vx
            })
            .collect(),
        indices,
    };
    if normals.is_none() {
        let mut acc = vec![Vec3::ZERO; n];
        for t in mesh.indices.chunks_exact(3) {
            let p = |k: usize| Vec3::from(mesh.vertices[t[k] as usize].position);
            let face = (p(1) - p(0)).cross(p(2) - p(0));
            for &k in t {
                acc[k as usize] += face;
            }
        }
        for (v, a) in mesh.vertices.iter_mut().zip(acc) {
            v.normal = a.normalize_or(Vec3::Y).to_array();
        }
    }
    Ok(mesh)
}

/// The material's KHR_texture_transform as a function of the texture coordinates.
fn transform_uv(material: &::gltf::Material<'_>) -> impl Fn(Vec2) -> Vec2 + use<> {
    let t = material
        .pbr_metallic_roughness()
        .base_color_texture()
        .and_then(|i| i.texture_transform())
        .map(|t| (Vec2::from(t.offset()), t.rotation(), Vec2::from(t.scale())));
    move |uv: Vec2| match t {
        Some((offset, rotation, scale)) => {
            let s = uv * scale;
            let (sin, cos) = rotation.sin_cos();
            Vec2::new(cos * s.x + sin * s.y, -sin * s.x + cos * s.y) + offset
        }
        None => uv,
    }
}

/// A material with its base-colour texture decoded (each image once).
fn read_material(
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
                        read_image(&image, buffers, dir).map_err(|e| format!("{name}: {e}"))?,
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
    })
}

/// Decodes an image (PNG or JPEG), refusing one over [`MAX_IMAGE_SIDE`] before decoding.
fn read_image(image: &::gltf::Image<'_>, buffers: &[Vec<u8>], dir: &Path) -> Res<Rgba8Image> {
    let label = match image.name() {
        Some(n) => format!("image {} `{n}`", image.index()),
        None => format!("image {}", image.index()),
    };
    let bytes: std::borrow::Cow<'_, [u8]> = match image.source() {
        ::gltf::image::Source::View { view, .. } => {
            let buffer = buffers
                .get(view.buffer().index())
                .ok_or_else(|| format!("{label}: its buffer is missing"))?;
            let end = view.offset().checked_add(view.length());
            match end.and_then(|end| buffer.get(view.offset()..end)) {
                Some(b) => b.into(),
                None => return Err(format!("{label}: buffer view {} is out of range", view.index())),
            }
        }
        ::gltf::image::Source::Uri { uri, .. } => read_uri(uri, dir)
            .map_err(|e| format!("{label} (`{}`): {e}", uri.chars().take(80).collect::<String>()))?
            .into(),
    };
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(&bytes[..]))
            .with_guessed_format()
            .map_err(|e| format!("{label}: {e}"))
    };
    let format = reader()?.format();
    if format.is_none() {
        return Err(format!(
            "{label}: not a PNG or JPEG image; re-export with PNG or JPEG textures"
        ));
    }
    let (w, h) = reader()?
        .into_dimensions()
        .map_err(|e| format!("{label}: {e}"))?;
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(format!(
            "{label} is {w}x{h}; canopy takes textures up to {MAX_IMAGE_SIDE} pixels a side: scale it down"
        ));
    }
    // Deflate expands at most about 1032:1: an image claiming more pixels than its data
    // could hold is refused before its pixels are allocated.
    let decoded = 4 * u64::from(w) * u64::from(h);
    if decoded > 1032 * bytes.len() as u64 + (1 << 16) {
        return Err(format!(
            "{label} claims {w}x{h} pixels but holds only {} bytes; the image is damaged",
            bytes.len()
        ));
    }
    let mut r = reader()?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(16 * u64::from(MAX_IMAGE_SIDE) * u64::from(MAX_IMAGE_SIDE));
    r.limits(limits);
    let img = r.decode().map_err(|e| format!("{label}: {e}"))?.to_rgba8();
    Ok(Rgba8Image {
        width: img.width(),
        height: img.height(),
        pixels: img.into_raw(),
    })
}
