//! The list of methods: what callers name in a frame, on the command line and in the
//! viewer. What each one is (its name, whether it needs a bake...) its module declares
//! ([`super::info`]).

/// How the forest is drawn. Each method can draw the whole scene alone; its module says how
/// (and [`super::info`] what it is).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// [`super::geometry`], the ground truth.
    #[default]
    Geometry,
    /// [`super::btf`].
    Btf,
    /// [`super::billboard`].
    Billboard,
    /// [`super::texel`].
    Texel,
    /// [`super::hybrid`].
    Hybrid,
    /// [`super::impostor`].
    Impostor,
    /// [`super::surfel`].
    Surfel,
}

impl Method {
    pub const ALL: &'static [Method] = &[
        Method::Geometry,
        Method::Btf,
        Method::Billboard,
        Method::Texel,
        Method::Hybrid,
        Method::Impostor,
        Method::Surfel,
    ];

    pub fn name(self) -> &'static str {
        super::info(self).name
    }

    /// The method draws baked images (and needs a bake).
    pub fn needs_bake(self) -> bool {
        super::info(self).needs_bake
    }

    /// The method keeps state that follows the sun, rebuilt when it moves.
    pub fn follows_sun(self) -> bool {
        super::info(self).follows_sun
    }

    pub fn parse(s: &str) -> Option<Method> {
        Self::ALL.iter().copied().find(|m| m.name() == s)
    }
}
