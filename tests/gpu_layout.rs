//! Every uniform and storage struct the Rust side uploads has the size and field offsets
//! that the WGSL declaration gives it (naga's layouter, so no GPU is needed): a field added
//! on one side only, or a `vec3` whose 16-byte slot is not filled, fails here instead of
//! shading a frame with shifted values.

use std::mem::{offset_of, size_of};

use canopy::render::method::btf::far::{
    DirSetGpu, FarParamsGpu, FarShadeGpu, FarTreeGpu, SortStepGpu,
};
use canopy::render::method::btf::far_canopy::CanopyGpuParams;
use canopy::render::method::btf::{BillboardGpu, NearDrawGpu};
use canopy::render::self_shadow::SelfLightGpu;
use canopy::render::uniforms::FrameUniforms;
use canopy::render::world_gpu::{PartSetGpu, TreeGpu};

/// (size, [(field, offset)]) of a Rust struct, fields named as in WGSL.
macro_rules! rust_layout {
    ($t:ty { $($f:ident),* $(,)? }) => {
        (size_of::<$t>(), vec![$((stringify!($f), offset_of!($t, $f))),*])
    };
}

/// (span, [(member, offset)]) of the WGSL struct `name` in `module`'s source.
fn wgsl_layout(source: &str, name: &str) -> (usize, Vec<(String, usize)>) {
    let module = naga::front::wgsl::parse_str(source).expect("the module parses");
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .expect("naga lays the module out");
    for (handle, ty) in module.types.iter() {
        if ty.name.as_deref() != Some(name) {
            continue;
        }
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("{name} is not a struct");
        };
        assert_eq!(layouter[handle].size, *span);
        let fields = members
            .iter()
            .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
            .collect();
        return (*span as usize, fields);
    }
    panic!("no struct {name} in the module");
}

fn check(what: &str, wgsl: (usize, Vec<(String, usize)>), rust: (usize, Vec<(&str, usize)>)) {
    let mut problems = Vec::new();
    if wgsl.0 != rust.0 {
        problems.push(format!("size: WGSL {} bytes, Rust {}", wgsl.0, rust.0));
    }
    for (name, offset) in &wgsl.1 {
        match rust.1.iter().find(|(n, _)| n == name) {
            Some((_, o)) if o == offset => {}
            Some((_, o)) => problems.push(format!("{name}: WGSL offset {offset}, Rust {o}")),
            None => problems.push(format!("{name}: in WGSL, not in Rust")),
        }
    }
    for (name, _) in &rust.1 {
        if !wgsl.1.iter().any(|(n, _)| n == name) {
            problems.push(format!("{name}: in Rust, not in WGSL"));
        }
    }
    assert!(problems.is_empty(), "{what}:\n{}", problems.join("\n"));
}

#[test]
fn frame_uniforms_match_frame_wgsl() {
    let rust = rust_layout!(FrameUniforms {
        view_proj,
        inv_view_proj,
        light_view_proj,
        camera_pos,
        fog_density,
        camera_forward,
        exposure,
        sun_dir,
        shadows_on,
        sun_color,
        pcf_radius,
        sky_ambient,
        sky_vis_count,
        ground_ambient,
        sky_vis_texel_world,
        sky_zenith,
        pixel_classes,
        sky_horizon,
        hybrid_cascades,
        cascade_splits,
        cascade_texel_uv,
        cascade_texel_world,
        ground_half,
        ground_light_view_proj,
        ground_alpha_on,
        terrain_depth_on,
        ground_texel_world,
        ground_uv_scale,
        overdraw,
        studio_output,
        studio_depth_near,
        studio_depth_scale,
        studio_pad,
    });
    // Every module sees the same block; one is enough to lay it out.
    check(
        "Frame",
        wgsl_layout(&canopy::render::shaders::sky(), "Frame"),
        rust,
    );
}

#[test]
fn billboard_record_matches_billboard_wgsl() {
    let rust = rust_layout!(BillboardGpu {
        center,
        radius,
        plane_right,
        planes,
        plane_up,
        opacity,
        obj_right,
        _pad0,
        obj_up,
        _pad1,
        view_index,
        layer_base,
        light_index,
        light_count,
        view_weight,
        view_count,
        light_weight,
        light_blend,
        tint,
        mode,
        vcm_box_origin,
        parent_direct,
        vcm_box_scale,
        parent_sky,
        vcm_direct,
        vcm_sky,
    });
    for source in [
        canopy::render::shaders::btf(),
        canopy::render::shaders::ground_map(),
        canopy::render::shaders::btf_far(),
    ] {
        check("Billboard", wgsl_layout(&source, "Billboard"), rust.clone());
    }
}

#[test]
fn instancing_structs_match_instancing_wgsl() {
    let source = canopy::render::shaders::geometry();
    check(
        "TreeInstance",
        wgsl_layout(&source, "TreeInstance"),
        rust_layout!(TreeGpu { model, tint }),
    );
    check(
        "PartSet",
        wgsl_layout(&source, "PartSet"),
        rust_layout!(PartSetGpu {
            count,
            alpha_cutoff,
            textured,
            _pad2,
            terrain_map
        }),
    );
    check(
        "SelfLight",
        wgsl_layout(&source, "SelfLight"),
        rust_layout!(SelfLightGpu {
            matrix,
            texel_world,
            layer,
            _pad0,
            _pad1
        }),
    );
}

#[test]
fn texel_record_matches_texel_wgsl() {
    use canopy::render::method::texel::TexelGpu;
    let rust = rust_layout!(TexelGpu {
        model,
        world_to_object,
        box_min,
        spacing,
        box_size,
        voxel,
        atlas_origin,
        volume_dw,
        atlas_extent,
        lod,
        light_index,
        mode,
        light_weight,
        lights,
        tint,
        scale,
        vcm_min,
        max_steps,
        vcm_inv_size,
        slices,
        vcm_direct,
        vcm_sky,
    });
    check(
        "Texel",
        wgsl_layout(&canopy::render::shaders::texel(), "Texel"),
        rust,
    );
}

#[test]
fn stack_record_matches_texel_wgsl() {
    use canopy::render::method::texel::stacks::StackGpu;
    let rust = rust_layout!(StackGpu {
        origin,
        tile,
        used,
        texels,
        axis,
        cols,
        per_volume,
        level_offset,
        level,
        order,
        slices,
        pad,
    });
    check(
        "Stack",
        wgsl_layout(&canopy::render::shaders::texel(), "Stack"),
        rust,
    );
}

#[test]
fn tile_record_matches_texel_wgsl() {
    use canopy::render::method::texel::tiles::TileGpu;
    let rust = rust_layout!(TileGpu {
        origin,
        size,
        lo,
        corners,
        height,
        voxel,
        spacing,
        max_steps,
        atlas_origin,
        volume_dw,
        atlas_extent,
        lights,
        light_index,
        slices,
        light_weight,
        pad0,
        box_min,
        pad1,
        box_max,
        pad2,
    });
    check(
        "Tile",
        wgsl_layout(&canopy::render::shaders::texel(), "Tile"),
        rust,
    );
}

#[test]
fn far_tree_structs_match_btf_far_wgsl() {
    let source = canopy::render::shaders::btf_far();
    check(
        "FarTree",
        wgsl_layout(&source, "FarTree"),
        rust_layout!(FarTreeGpu {
            model,
            tint,
            species,
            bounds_min,
            _pad0,
            bounds_max,
            _pad1
        }),
    );
    check(
        "FarShade",
        wgsl_layout(&source, "FarShade"),
        rust_layout!(FarShadeGpu { direct, sky }),
    );
    check(
        "DirSet",
        wgsl_layout(&source, "DirSet"),
        rust_layout!(DirSetGpu {
            level,
            splits,
            bary,
            triangles,
            directions,
            count,
            _pad0,
            _pad1
        }),
    );
    let (size, fields) = rust_layout!(FarParamsGpu {
        camera,
        count,
        forward,
        plane_count,
        to_sun,
        weight_threshold,
        planes,
        overlay,
        mode,
        light_gain,
        plane_mode,
        vcm,
        species,
        views,
        lights,
        sort_n,
        near_count,
        limit,
        vcm_res,
        overlay_twig,
        near_draws,
        overlay_branch,
        near_slots,
        views_twig,
        views_branch,
        draws_at,
        bits_at,
        trees_at,
        near_room,
        light_bins,
        light_blend_first,
        canopy_near,
        canopy_far,
        sun_color,
        means_at,
        sky_ambient,
        layer_batches,
        ground_ambient,
        sort_args_at
    });
    check(
        "FarParams",
        wgsl_layout(&source, "FarParams"),
        (size, fields),
    );
    let canopy_source = canopy::render::shaders::canopy();
    check(
        "Canopy",
        wgsl_layout(&canopy_source, "Canopy"),
        rust_layout!(CanopyGpuParams {
            origin,
            texel,
            side,
            levels,
            lid_side,
            lid_texels,
            tile_cells,
            near,
            far,
            show_overlay,
            _pad0,
            overlay,
            _pad1
        }),
    );
    let (size, mut fields) = rust_layout!(SortStepGpu { k, j, _pad });
    let pad = fields.pop().expect("the padding").1;
    fields.extend([("_pad0", pad), ("_pad1", pad + 4)]);
    check("SortStep", wgsl_layout(&source, "SortStep"), (size, fields));
    check(
        "NearDraw",
        wgsl_layout(&source, "NearDraw"),
        rust_layout!(NearDrawGpu {
            tree,
            level,
            opacity,
            first
        }),
    );
}

#[test]
fn impostor_record_and_params_match_impostor_wgsl() {
    use canopy::render::method::impostor::prepare::{ImpostorGpu, ImpostorParams};
    let source = canopy::render::shaders::impostor();
    check(
        "Impostor",
        wgsl_layout(&source, "Impostor"),
        rust_layout!(ImpostorGpu {
            center,
            radius,
            axis_x,
            layer,
            axis_y,
            opacity,
            axis_z,
            mode,
            tint,
            parent_direct,
            vcm_box_origin,
            parent_sky,
            vcm_box_scale,
            _pad,
            vcm_direct,
            vcm_sky,
        }),
    );
    check(
        "ImpostorParams",
        wgsl_layout(&source, "ImpostorParams"),
        rust_layout!(ImpostorParams {
            frames,
            octa_layout,
            resolution,
            mips,
            alpha_cutoff,
            parallax,
            self_shadow,
            _pad,
        }),
    );
}

#[test]
fn surfel_structs_match_surfel_wgsl() {
    use canopy::render::method::surfel::gpu::{SurfelItem, SurfelParams, SurfelTreeGpu};
    let source = canopy::render::shaders::surfel();
    check(
        "SurfelParams",
        wgsl_layout(&source, "SurfelParams"),
        rust_layout!(SurfelParams {
            size,
            half_size,
            quarter_size,
            items,
            row,
            fill,
            mode,
            focal_px,
            self_shadow,
        }),
    );
    check(
        "SurfelTreeGpu",
        wgsl_layout(&source, "SurfelTreeGpu"),
        rust_layout!(SurfelTreeGpu {
            model,
            qmin,
            instance,
            qsize,
            scale,
            tint,
            _pad0,
            vcm_min,
            _pad1,
            vcm_inv_size,
            _pad2,
            vcm_direct,
            vcm_sky,
            vol_origin,
            vol_voxel,
            vol_dims,
            vol_offset,
        }),
    );
    check(
        "SurfelItem",
        wgsl_layout(&source, "SurfelItem"),
        rust_layout!(SurfelItem {
            tree,
            first,
            count,
            tolerance,
            level,
            spacing,
            _pad,
        }),
    );
}
