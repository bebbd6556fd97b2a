//! The reading half of the glTF import: files and URIs (each refused over its size limit
//! before it is read), buffers, accessors (bounds-checked before a byte is read), primitives
//! and images (their size checked before their pixels are allocated).

use std::path::Path;

use glam::Vec3;

use super::{MAX_FILE_BYTES, MAX_IMAGE_SIDE, Res, Rgba8Image};
use crate::model::mesh::{Mesh, Vertex};

/// Reads a whole file, refusing one over [`MAX_FILE_BYTES`] before reading it.
pub(super) fn read_file(path: &Path) -> Res<Vec<u8>> {
    if let Some(bytes) = super::embedded::lookup(path) {
        return Ok(bytes.to_vec());
    }
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
pub(super) fn read_uri(uri: &str, dir: &Path) -> Res<Vec<u8>> {
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
        return Err(format!(
            "URI `{uri}` is an absolute path; use a relative one"
        ));
    }
    read_file(&dir.join(rel))
}

pub(super) fn percent_decode(s: &str) -> String {
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

pub(super) fn base64_decode(s: &str) -> Option<Vec<u8>> {
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
pub(super) fn load_buffers(
    doc: &::gltf::Document,
    blob: Option<Vec<u8>>,
    dir: &Path,
) -> Res<Vec<Vec<u8>>> {
    let mut blob = blob;
    let mut out = Vec::new();
    for b in doc.buffers() {
        let data = match b.source() {
            ::gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                format!(
                    "buffer {} refers to the GLB binary chunk, which is missing",
                    b.index()
                )
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
pub(super) fn read_accessor(
    acc: &::gltf::Accessor<'_>,
    buffers: &[Vec<u8>],
    what: &str,
) -> Res<(Vec<f32>, usize)> {
    use ::gltf::accessor::DataType;
    let name = format!("{what} accessor {}", acc.index());
    if acc.sparse().is_some() {
        return Err(format!(
            "{name} is sparse; canopy does not read sparse accessors"
        ));
    }
    let view = acc
        .view()
        .ok_or_else(|| format!("{name} has no bufferView"))?;
    let dims = acc.dimensions().multiplicity();
    let comp = acc.data_type().size();
    let elem = dims * comp;
    let stride = view.stride().unwrap_or(elem);
    if stride < elem {
        return Err(format!(
            "{name}: byteStride {stride} is smaller than its element ({elem} bytes)"
        ));
    }
    let count = acc.count();
    if count == 0 {
        return Ok((Vec::new(), dims));
    }
    let out_of_range = || {
        format!(
            "{name} is out of range of its buffer view {} or buffer",
            view.index()
        )
    };
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
    let start = view
        .offset()
        .checked_add(acc.offset())
        .ok_or_else(out_of_range)?;
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
                    if normalized {
                        (v / 32767.0).max(-1.0)
                    } else {
                        v
                    }
                }
                DataType::U32 => u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32,
            };
            out.push(v);
        }
    }
    Ok((out, dims))
}

/// Indices as u32 (exact, unlike [`read_accessor`]'s floats).
pub(super) fn read_indices(
    acc: &::gltf::Accessor<'_>,
    buffers: &[Vec<u8>],
    vertices: usize,
    at: &str,
) -> Res<Vec<u32>> {
    use ::gltf::accessor::{DataType, Dimensions};
    let name = format!("{at}: indices accessor {}", acc.index());
    if acc.dimensions() != Dimensions::Scalar
        || !matches!(
            acc.data_type(),
            DataType::U8 | DataType::U16 | DataType::U32
        )
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
            return Err(format!(
                "{name}: index {v} is out of range of the {vertices} vertices"
            ));
        }
        out.push(v);
    }
    Ok(out)
}

/// One primitive as a mesh in its mesh's frame: positions, normals (computed, area-weighted,
/// where the file has none), texture coordinates of set `uv_set`, COLOR_0 in the colours.
pub(super) fn read_primitive(
    prim: &::gltf::Primitive<'_>,
    buffers: &[Vec<u8>],
    uv_set: u32,
    at: &str,
    warnings: &mut Vec<String>,
) -> Res<Mesh> {
    use ::gltf::mesh::Mode;
    use ::gltf::mesh::Semantic;
    let mode = prim.mode();
    if !matches!(
        mode,
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
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
        Ok(Some(
            read_accessor(&acc, buffers, &format!("{at}: {what}"))?.0,
        ))
    };
    let positions =
        float3(&Semantic::Positions, "POSITION")?.ok_or_else(|| format!("{at} has no POSITION"))?;
    let n = positions.len() / 3;
    let normals = float3(&Semantic::Normals, "NORMAL")?;
    if normals.as_ref().is_some_and(|v| v.len() != positions.len()) {
        return Err(format!("{at}: NORMAL and POSITION counts differ"));
    }
    let uvs = match prim.get(&Semantic::TexCoords(uv_set)) {
        Some(acc) => {
            let (v, dims) = read_accessor(&acc, buffers, &format!("{at}: TEXCOORD_{uv_set}"))?;
            if dims != 2 || v.len() / 2 != n {
                return Err(format!(
                    "{at}: TEXCOORD_{uv_set} must be VEC2, one per vertex"
                ));
            }
            Some(v)
        }
        None => None,
    };
    let colors = match prim.get(&Semantic::Colors(0)) {
        Some(acc) => {
            let (v, dims) = read_accessor(&acc, buffers, &format!("{at}: COLOR_0"))?;
            if !(dims == 3 || dims == 4) || v.len() / dims != n {
                return Err(format!(
                    "{at}: COLOR_0 must be VEC3 or VEC4, one per vertex"
                ));
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
                let color = colors
                    .as_ref()
                    .map_or(Vec3::ONE, |(v, d)| Vec3::from_slice(&v[d * i..d * i + 3]));
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

/// Decodes an image (PNG or JPEG), refusing one over [`MAX_IMAGE_SIDE`] before decoding.
pub(super) fn read_image(
    doc: &::gltf::Document,
    image: &::gltf::Image<'_>,
    buffers: &[Vec<u8>],
    dir: &Path,
) -> Res<Rgba8Image> {
    let label = match image.name() {
        Some(n) => format!("image {} `{n}`", image.index()),
        None => format!("image {}", image.index()),
    };
    // From the JSON, not `Image::source`, which unwraps a missing mimeType or uri.
    let json = doc.as_json().images.get(image.index());
    let view = json
        .and_then(|j| j.buffer_view.as_ref())
        .and_then(|v| doc.views().nth(v.value()));
    let uri = json.and_then(|j| j.uri.as_deref());
    let bytes: std::borrow::Cow<'_, [u8]> = match (view, uri) {
        (Some(view), _) => {
            let buffer = buffers
                .get(view.buffer().index())
                .ok_or_else(|| format!("{label}: its buffer is missing"))?;
            let end = view.offset().checked_add(view.length());
            match end.and_then(|end| buffer.get(view.offset()..end)) {
                Some(b) => b.into(),
                None => {
                    return Err(format!(
                        "{label}: buffer view {} is out of range",
                        view.index()
                    ));
                }
            }
        }
        (None, None) => return Err(format!("{label} has neither a uri nor a bufferView")),
        (None, Some(uri)) => read_uri(uri, dir)
            .map_err(|e| {
                format!(
                    "{label} (`{}`): {e}",
                    uri.chars().take(80).collect::<String>()
                )
            })?
            .into(),
    };
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(&bytes[..]))
            .with_guessed_format()
            .map_err(|e| format!("{label}: {e}"))
    };
    // glTF 2.0's core images; other formats the bytes may look like are refused here.
    let format = reader()?.format();
    if !matches!(
        format,
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg)
    ) {
        let what = format.map_or("not a PNG or JPEG image".to_owned(), |f| {
            format!("a {f:?} image, not PNG or JPEG")
        });
        return Err(format!(
            "{label}: {what}; re-export with PNG or JPEG textures"
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

/// The JSON and the binary chunk of a GLB (`bytes` itself and none when it is a `.gltf`).
pub(super) fn split_glb(bytes: &[u8]) -> Res<(&[u8], Option<&[u8]>)> {
    if !bytes.starts_with(b"glTF") {
        return Ok((bytes, None));
    }
    let word = |at: usize| {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
            .ok_or_else(|| "a GLB cut short in its header".to_string())
    };
    if word(4)? != 2 {
        return Err(format!(
            "a GLB of version {}; canopy reads version 2",
            word(4)?
        ));
    }
    let length = word(8)?;
    if length < 20 || length > bytes.len() {
        return Err(format!(
            "a GLB whose header gives {length} bytes, but the file has {}",
            bytes.len()
        ));
    }
    let chunk = |at: usize, kind: u32, name: &str| -> Res<Option<&[u8]>> {
        if at + 8 > length {
            return Ok(None);
        }
        let len = word(at)?;
        if word(at + 4)? != kind as usize {
            return Err(format!(
                "a GLB whose chunk at byte {at} is not its {name} chunk"
            ));
        }
        let end = (at + 8)
            .checked_add(len)
            .filter(|&e| e <= length)
            .ok_or_else(|| format!("a GLB whose {name} chunk runs past its end"))?;
        Ok(Some(&bytes[at + 8..end]))
    };
    let json = chunk(12, 0x4E4F_534A, "JSON")?
        .ok_or_else(|| "a GLB without its JSON chunk".to_string())?;
    let bin_at = (20 + json.len() + 3) & !3;
    let bin = chunk(bin_at, 0x004E_4942, "BIN")?;
    Ok((json, bin))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_uris_and_escaped_paths_decode() {
        assert_eq!(base64_decode("aGk=").as_deref(), Some(&b"hi"[..]));
        assert_eq!(
            base64_decode("AAEC/w==").as_deref(),
            Some(&[0, 1, 2, 255][..])
        );
        assert_eq!(base64_decode("a*b"), None);
        assert_eq!(percent_decode("Leaf%20Pine.png"), "Leaf Pine.png");
        assert_eq!(percent_decode("50%.png"), "50%.png");
        assert_eq!(percent_decode("%zz"), "%zz");
    }
}
