//! The list of methods: what callers name in a frame, on the command line and in the
//! viewer. A leaf module, so that the frame's description can name a method without
//! importing any.

/// How the forest is drawn. Each method can draw the whole scene alone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Every leaf, needle and branch as triangles: the ground truth.
    #[default]
    Geometry,
    /// BTF billboards of the twig / main branch / tree hierarchy (needs a bake).
    Btf,
    /// One camera-facing image per tree from a single baked view and light: the floor.
    Billboard,
    /// Each tree as a volumetric texel: its baked volumes sliced parallel to the screen
    /// (needs a bake with texel volumes).
    Texel,
    /// `btf`, with a tree drawn as geometry wherever even its twig level's texels project
    /// above the LOD bound (cross-faded): no more detail than the view needs, and no less.
    Hybrid,
    /// One quad per tree showing its species' octahedral impostor: 3 baked frames blended
    /// with depth parallax, lit per pixel (needs a bake with impostors).
    Impostor,
}

impl Method {
    pub const ALL: &'static [Method] = &[
        Method::Geometry,
        Method::Btf,
        Method::Billboard,
        Method::Texel,
        Method::Hybrid,
        Method::Impostor,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::Geometry => "geometry",
            Method::Btf => "btf",
            Method::Billboard => "billboard",
            Method::Texel => "texel",
            Method::Hybrid => "hybrid",
            Method::Impostor => "impostor",
        }
    }

    /// The method draws baked images (and needs a bake).
    pub fn needs_bake(self) -> bool {
        matches!(
            self,
            Method::Btf | Method::Billboard | Method::Texel | Method::Hybrid | Method::Impostor
        )
    }

    /// The method draws the BTF hierarchy and takes the `btf` knobs.
    pub fn is_btf(self) -> bool {
        matches!(self, Method::Btf | Method::Hybrid)
    }

    pub fn parse(s: &str) -> Option<Method> {
        Self::ALL.iter().copied().find(|m| m.name() == s)
    }
}
