//! The levels of the tree hierarchy (twig → main branch → tree) and a small container holding
//! one value per level. The BTF image sets, the visibility cube maps and the LOD choice are all
//! per level; this is the one place the triple is spelled out.

use std::ops::{Index, IndexMut};

/// A level of the tree hierarchy, finest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Level {
    /// One twig: its stem and its leaves or needles.
    Twig,
    /// One main branch: its limb and its twigs.
    Branch,
    /// The whole tree: trunk, main branches and the trunk's own twigs.
    Tree,
}

impl Level {
    /// Every level, finest first.
    pub const ALL: [Level; 3] = [Level::Twig, Level::Branch, Level::Tree];

    /// Position in [`Level::ALL`]: 0 twig, 1 main branch, 2 tree.
    pub const fn index(self) -> usize {
        match self {
            Level::Twig => 0,
            Level::Branch => 1,
            Level::Tree => 2,
        }
    }

    /// The name used in messages and progress: "twig", "main branch" or "tree".
    pub const fn name(self) -> &'static str {
        match self {
            Level::Twig => "twig",
            Level::Branch => "main branch",
            Level::Tree => "tree",
        }
    }

    /// The next finer level (the parts this level is made of), if any.
    pub const fn finer(self) -> Option<Level> {
        match self {
            Level::Tree => Some(Level::Branch),
            Level::Branch => Some(Level::Twig),
            Level::Twig => None,
        }
    }
}

/// One value per level. Serialised as `{ "twig": .., "main_branch": .., "tree": .. }`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub struct PerLevel<T> {
    pub twig: T,
    #[serde(rename = "main_branch")]
    pub branch: T,
    pub tree: T,
}

impl<T> PerLevel<T> {
    /// The value of every level from `f(level)`.
    pub fn from_fn(mut f: impl FnMut(Level) -> T) -> Self {
        PerLevel {
            twig: f(Level::Twig),
            branch: f(Level::Branch),
            tree: f(Level::Tree),
        }
    }

    /// The value of every level from `f(level)`, or the first error.
    pub fn try_from_fn<E>(mut f: impl FnMut(Level) -> Result<T, E>) -> Result<Self, E> {
        Ok(PerLevel {
            twig: f(Level::Twig)?,
            branch: f(Level::Branch)?,
            tree: f(Level::Tree)?,
        })
    }

    /// Every value mapped by `f`.
    pub fn map<U>(self, mut f: impl FnMut(T) -> U) -> PerLevel<U> {
        PerLevel {
            twig: f(self.twig),
            branch: f(self.branch),
            tree: f(self.tree),
        }
    }

    /// The values, finest first (as an array's `iter`).
    pub fn iter(&self) -> impl Iterator<Item = &T> {
        [&self.twig, &self.branch, &self.tree].into_iter()
    }

    /// (level, value) pairs, finest first.
    pub fn iter_levels(&self) -> impl Iterator<Item = (Level, &T)> {
        Level::ALL.into_iter().map(move |l| (l, &self[l]))
    }
}

impl<T> Index<Level> for PerLevel<T> {
    type Output = T;

    fn index(&self, level: Level) -> &T {
        match level {
            Level::Twig => &self.twig,
            Level::Branch => &self.branch,
            Level::Tree => &self.tree,
        }
    }
}

impl<T> IndexMut<Level> for PerLevel<T> {
    fn index_mut(&mut self, level: Level) -> &mut T {
        match level {
            Level::Twig => &mut self.twig,
            Level::Branch => &mut self.branch,
            Level::Tree => &mut self.tree,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_numbered_and_named_finest_first() {
        for (i, l) in Level::ALL.into_iter().enumerate() {
            assert_eq!(l.index(), i);
        }
        let names = Level::ALL.map(Level::name);
        assert_eq!(names, ["twig", "main branch", "tree"]);
        assert_eq!(Level::Tree.finer(), Some(Level::Branch));
        assert_eq!(Level::Branch.finer(), Some(Level::Twig));
        assert_eq!(Level::Twig.finer(), None);
    }

    #[test]
    fn per_level_indexes_maps_and_iterates_finest_first() {
        let mut p = PerLevel::from_fn(|l| l.index() as u32 * 10);
        assert_eq!((p.twig, p.branch, p.tree), (0, 10, 20));
        p[Level::Branch] += 1;
        assert_eq!(p[Level::Branch], 11);
        let doubled = p.map(|v| v * 2);
        assert_eq!(doubled.tree, 40);
        let order: Vec<(Level, u32)> = p.iter_levels().map(|(l, &v)| (l, v)).collect();
        assert_eq!(
            order,
            [(Level::Twig, 0), (Level::Branch, 11), (Level::Tree, 20)]
        );
        assert_eq!(p.iter().sum::<u32>(), 31);
    }

    #[test]
    fn per_level_serialises_with_the_json_keys() {
        let p = PerLevel {
            twig: 1u32,
            branch: 2,
            tree: 3,
        };
        let json = serde_json::to_value(p).unwrap();
        assert_eq!(
            json,
            serde_json::json!({ "twig": 1, "main_branch": 2, "tree": 3 })
        );
    }
}
