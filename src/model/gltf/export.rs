//! Writes a procedural tree as glTF 2.0 binary (`.glb`), so that canopy's species open in
//! Blender or an engine, and come back as a species (`gltf = "..."`).
//!
//! The tree's three meshes (trunk, main-branch limb, twig) are written once each and
//! placed by nodes, as the model holds them: the trunk; one node per main branch (its
//! limb) with a child per twig on it; one node per twig on the trunk. Each mesh has up to
//! two primitives: bark (opaque) and foliage (double-sided, marked
//! `"extras": {"canopy": {"foliage": true}}` so that canopy lights it as foliage again).
//! Colours are the vertices' (`COLOR_0`, linear), over a white base colour.

use glam::Mat4;
use serde_json::{Value, json};

use super::Res;
use crate::model::mesh::Mesh;
use crate::model::tree::TreeModel;

const GLB_MAGIC: u32 = 0x4654_6C67;
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The JSON and binary parts being built.
#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Builder {
    /// Appends `bytes` (4-byte aligned) as a buffer view; returns its index.
    fn view(&mut self, bytes: &[u8], target: u32) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views.push(json!({
            "buffer": 0,
            "byteOffset": offset,
            "byteLength": bytes.len(),
            "target": target,
        }));
        self.views.len() - 1
    }

    /// A VEC3 float accessor of `values` (with its bounds when `bounds`).
    fn vec3(&mut self, values: &[[f32; 3]], bounds: bool) -> usize {
        let bytes: Vec<u8> = values
            .iter()
            .flatten()
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let view = self.view(&bytes, ARRAY_BUFFER);
        let mut acc = json!({
            "bufferView": view,
            "componentType": FLOAT,
            "count": values.len(),
            "type": "VEC3",
        });
        if bounds {
            let mut min = [f32::INFINITY; 3];
            let mut max = [f32::NEG_INFINITY; 3];
            for v in values {
                for k in 0..3 {
                    min[k] = min[k].min(v[k]);
                    max[k] = max[k].max(v[k]);
                }
            }
            acc["min"] = json!(min);
            acc["max"] = json!(max);
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }

    /// A SCALAR u32 index accessor.
    fn indices(&mut self, indices: &[u32]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, ELEMENT_ARRAY_BUFFER);
        self.accessors.push(json!({
            "bufferView": view,
            "componentType": UNSIGNED_INT,
            "count": indices.len(),
            "type": "SCALAR",
        }));
        self.accessors.len() - 1
    }

    /// The glTF mesh of `mesh`: its vertices once, a primitive per material (bark 0,
    /// foliage 1) with the triangles whose first vertex is of it. None for an empty mesh.
    fn mesh(&mut self, name: &str, mesh: &Mesh) -> Option<Value> {
        if mesh.indices.is_empty() || mesh.vertices.is_empty() {
            return None;
        }
        let positions: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.position).collect();
        let normals: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.normal).collect();
        let colors: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.color).collect();
        let position = self.vec3(&positions, true);
        let normal = self.vec3(&normals, false);
        let color = self.vec3(&colors, false);
        let mut parts: [Vec<u32>; 2] = [Vec::new(), Vec::new()];
        for tri in mesh.indices.chunks_exact(3) {
            let foliage = mesh
                .vertices
                .get(tri[0] as usize)
                .is_some_and(|v| v.foliage > 0.5);
            parts[usize::from(foliage)].extend_from_slice(tri);
        }
        let primitives: Vec<Value> = parts
            .iter()
            .enumerate()
            .filter(|(_, p)| !p.is_empty())
            .map(|(material, p)| {
                let indices = self.indices(p);
                json!({
                    "attributes": {"POSITION": position, "NORMAL": normal, "COLOR_0": color},
                    "indices": indices,
                    "material": material,
                    "mode": 4,
                })
            })
            .collect();
        Some(json!({"name": name, "primitives": primitives}))
    }
}

/// A node placing mesh `mesh` by `m` (identity: no matrix), with `children`.
fn node(name: String, mesh: Option<usize>, m: Mat4, children: Vec<usize>) -> Value {
    let mut n = json!({ "name": name });
    if let Some(mesh) = mesh {
        n["mesh"] = json!(mesh);
    }
    if m != Mat4::IDENTITY {
        n["matrix"] = json!(m.to_cols_array());
    }
    if !children.is_empty() {
        n["children"] = json!(children);
    }
    n
}

/// The `.glb` bytes of `tree` (a procedural tree: trunk, limbs and twigs; an imported tree
/// has its whole mesh as the trunk and is written as one mesh).
pub fn export_glb(tree: &TreeModel) -> Res<Vec<u8>> {
    let mut b = Builder::default();
    let mut meshes: Vec<Value> = Vec::new();
    let mut add = |b: &mut Builder, name: &str, mesh: &Mesh| {
        b.mesh(name, mesh).map(|m| {
            meshes.push(m);
            meshes.len() - 1
        })
    };
    let trunk = add(&mut b, "trunk", &tree.trunk);
    let limb = add(&mut b, "main branch", &tree.branch_limb);
    let twig = add(&mut b, "twig", &tree.twig);
    if trunk.is_none() && limb.is_none() && twig.is_none() {
        return Err(format!("species `{}` has no triangles", tree.name));
    }
    // Node 0 is the tree; its children follow in the order made.
    let mut nodes: Vec<Value> = vec![Value::Null];
    let mut top: Vec<usize> = Vec::new();
    let push = |nodes: &mut Vec<Value>, n: Value| {
        nodes.push(n);
        nodes.len() - 1
    };
    if trunk.is_some() {
        let n = push(
            &mut nodes,
            node("trunk".into(), trunk, Mat4::IDENTITY, vec![]),
        );
        top.push(n);
    }
    for (i, m) in tree.tree_branches.iter().enumerate() {
        let twigs: Vec<usize> = if twig.is_some() {
            tree.branch_twigs
                .iter()
                .enumerate()
                .map(|(j, t)| push(&mut nodes, node(format!("twig {i}.{j}"), twig, *t, vec![])))
                .collect()
        } else {
            Vec::new()
        };
        let n = push(
            &mut nodes,
            node(format!("main branch {i}"), limb, *m, twigs),
        );
        top.push(n);
    }
    if twig.is_some() {
        for (k, t) in tree.tree_twigs.iter().enumerate() {
            let n = push(&mut nodes, node(format!("twig {k}"), twig, *t, vec![]));
            top.push(n);
        }
    }
    nodes[0] = node(tree.name.clone(), None, Mat4::IDENTITY, top);
    let white = json!({"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0});
    let root = json!({
        "asset": {"version": "2.0", "generator": concat!("canopy ", env!("CARGO_PKG_VERSION"), " export")},
        "scene": 0,
        "scenes": [{"name": tree.name, "nodes": [0]}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": [
            {"name": "bark", "pbrMetallicRoughness": white},
            {
                "name": "foliage",
                "doubleSided": true,
                "pbrMetallicRoughness": white,
                "extras": {"canopy": {"foliage": true}},
            },
        ],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.bin.len()}],
    });
    let mut text = serde_json::to_vec(&root).map_err(|e| format!("cannot write the JSON: {e}"))?;
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut bin = b.bin;
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let total = u32::try_from(total).map_err(|_| "the tree is over 4 GB as glTF".to_string())?;
    let mut out = Vec::with_capacity(total as usize);
    for word in [GLB_MAGIC, 2, total, text.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    out.extend_from_slice(&text);
    for word in [bin.len() as u32, CHUNK_BIN] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    out.extend_from_slice(&bin);
    Ok(out)
}
