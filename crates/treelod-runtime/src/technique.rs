//! The one list of techniques: every way a tree can be drawn from a container (each of its
//! representations, the baselines, the full mesh), by the names every layer uses — the renderer's
//! settings, the frame statistics, `eval`, `bench`, `render`, `view` and `dump`.
//!
//! A technique needs data only some containers hold (ellipsoids, planes, priority lists, the
//! baselines); a tree whose container lacks it is drawn with [`Technique::FALLBACK`], the
//! sequential point tree every container holds.

use treelod_format::{Container, billboard_kind};

/// How a tree is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Technique {
    /// Every triangle of the source mesh, no level of detail: the reference's cost.
    #[cfg_attr(feature = "clap", value(name = "full"))]
    Full,
    /// Triangles and points (Gilet et al. 2005) as sequential point trees: every container holds
    /// them.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "spt"))]
    Spt,
    /// Pruned leaves scaled by the optimised `s_opt(λ)` (Neubert et al. 2011), the sequential point
    /// tree below a projected height (spec §6.11).
    #[cfg_attr(feature = "clap", value(name = "prune-opt"))]
    PruneOpt,
    /// Pruned leaves scaled by Cook's `1/λ` (stochastic pruning, the baseline Neubert et al.
    /// improve on).
    #[cfg_attr(feature = "clap", value(name = "prune-cook"))]
    PruneCook,
    /// Leaf-cluster impostor planes (Garcia et al. 2005, spec §6.10), bark as the branch lines
    /// where the container has them, else the LoD chain's bark level or every bark triangle.
    #[cfg_attr(feature = "clap", value(name = "impostors"))]
    Impostors,
    /// Clustered leaf ellipsoids and branch lines (Clasen et al. 2011, spec §6.8, §6.9).
    #[cfg_attr(feature = "clap", value(name = "ellipsoids"))]
    Ellipsoids,
    /// Baseline: a discrete LoD chain from meshoptimizer's simplifiers (spec §6.12).
    #[cfg_attr(feature = "clap", value(name = "lod-chain"))]
    LodChain,
    /// Baseline: one camera-facing billboard per tree (spec §6.13).
    #[cfg_attr(feature = "clap", value(name = "billboard"))]
    Billboard,
    /// Baseline: crossed billboards, three fixed quads per tree (spec §6.13).
    #[cfg_attr(feature = "clap", value(name = "crossed"))]
    Crossed,
    /// Baseline: an octahedral impostor, one quad facing the viewer textured from the tree baked
    /// over the upper hemisphere, the three views nearest the view direction blended (spec
    /// §6.13.1).
    #[cfg_attr(feature = "clap", value(name = "octahedral"))]
    Octahedral,
}

impl Technique {
    /// Every technique, in the order tables and plots list them.
    pub const ALL: [Self; 10] = [
        Self::Full,
        Self::Spt,
        Self::PruneOpt,
        Self::PruneCook,
        Self::Impostors,
        Self::Ellipsoids,
        Self::LodChain,
        Self::Billboard,
        Self::Crossed,
        Self::Octahedral,
    ];

    /// How many techniques there are: the length of per-technique arrays.
    pub const COUNT: usize = Self::ALL.len();

    /// What a tree whose container lacks a technique's data is drawn with.
    pub const FALLBACK: Self = Self::Spt;

    /// The technique's index in [`Self::ALL`] (and in per-technique arrays).
    #[must_use]
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The name the command line takes (`--technique`) and reports print.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Spt => "spt",
            Self::PruneOpt => "prune-opt",
            Self::PruneCook => "prune-cook",
            Self::Impostors => "impostors",
            Self::Ellipsoids => "ellipsoids",
            Self::LodChain => "lod-chain",
            Self::Billboard => "billboard",
            Self::Crossed => "crossed",
            Self::Octahedral => "octahedral",
        }
    }

    /// A few words for panels and messages.
    #[must_use]
    pub const fn label(self) -> &'static str {
        match self {
            Self::Full => "full mesh",
            Self::Spt => "triangles + points",
            Self::PruneOpt => "pruned leaves (s_opt)",
            Self::PruneCook => "pruned leaves (Cook)",
            Self::Impostors => "impostor planes",
            Self::Ellipsoids => "ellipsoids + lines",
            Self::LodChain => "LoD chain",
            Self::Billboard => "billboard",
            Self::Crossed => "crossed billboards",
            Self::Octahedral => "octahedral impostor",
        }
    }

    /// What it is and where it comes from, for reports (eval's JSON summary).
    #[must_use]
    pub const fn description(self) -> &'static str {
        match self {
            Self::Full => "every triangle of the source mesh, no level of detail",
            Self::Spt => "triangles and points (Gilet 2005, sequential point trees): what every container holds",
            Self::PruneOpt => "pruning with s_opt (Neubert 2011)",
            Self::PruneCook => "pruning with s_Cook = 1/lambda (stochastic baseline)",
            Self::Impostors => "leaf-cluster impostor planes (Garcia 2005)",
            Self::Ellipsoids => "clustered ellipsoids and lines (Clasen 2011)",
            Self::LodChain => "baseline: meshoptimizer LoD chain switched at s_min pixels of error",
            Self::Billboard => "baseline: one camera-facing billboard per tree",
            Self::Crossed => "baseline: crossed billboards (3 fixed quads per tree)",
            Self::Octahedral => {
                "baseline: octahedral impostor (one quad, the tree baked from views over the hemisphere)"
            }
        }
    }

    /// The colour, linear RGB, debug views draw its trees with (the renderer's
    /// `DebugView::Techniques`): full grey, spt blue, prune-opt green, prune-cook dark green,
    /// impostors yellow, ellipsoids cyan, lod-chain red, billboard magenta, crossed violet,
    /// octahedral pink.
    #[must_use]
    pub const fn colour(self) -> [f32; 3] {
        match self {
            Self::Full => [0.6, 0.6, 0.6],
            Self::Spt => [0.2, 0.5, 0.95],
            Self::PruneOpt => [0.3, 0.8, 0.3],
            Self::PruneCook => [0.1, 0.5, 0.2],
            Self::Impostors => [0.95, 0.75, 0.15],
            Self::Ellipsoids => [0.2, 0.8, 0.8],
            Self::LodChain => [0.9, 0.3, 0.2],
            Self::Billboard => [0.85, 0.35, 0.85],
            Self::Crossed => [0.5, 0.3, 0.9],
            Self::Octahedral => [0.95, 0.5, 0.65],
        }
    }

    /// The technique named `name` ([`Self::name`]).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The data of a container this technique draws, which only some containers hold; `None`
    /// for the full mesh and the point tree, which every container holds.
    #[must_use]
    pub const fn needs(self) -> Option<Data> {
        match self {
            Self::Full | Self::Spt => None,
            Self::PruneOpt | Self::PruneCook => Some(Data::PriorityLists),
            Self::Impostors => Some(Data::Planes),
            Self::Ellipsoids => Some(Data::Ellipsoids),
            Self::LodChain => Some(Data::LodChain),
            Self::Billboard | Self::Crossed | Self::Octahedral => Some(Data::Billboards),
        }
    }

    /// Whether `container` holds what this technique draws (else its trees are drawn with
    /// [`Self::FALLBACK`]).
    #[must_use]
    pub fn held_by(self, container: &Container) -> bool {
        match self {
            Self::Full | Self::Spt => true,
            Self::PruneOpt | Self::PruneCook => !container.prune_leaves().is_empty(),
            Self::Impostors => !container.planes().is_empty(),
            // Lines draw the bark of trees drawn with ellipsoids: a container with lines alone is
            // drawn with the point tree.
            Self::Ellipsoids => !container.ellipsoids().is_empty(),
            Self::LodChain => !container.lod_levels().is_empty(),
            Self::Billboard => container.billboards().iter().any(|b| b.kind == billboard_kind::FACING),
            Self::Crossed => container.billboards().iter().any(|b| b.kind == billboard_kind::CROSSED),
            Self::Octahedral => !container.octahedral().is_empty(),
        }
    }

    /// Whether this technique is one of the baselines users draw without treelod.
    #[must_use]
    pub const fn is_baseline(self) -> bool {
        matches!(self, Self::LodChain | Self::Billboard | Self::Crossed | Self::Octahedral)
    }
}

impl std::fmt::Display for Technique {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Optional data of a container that a technique draws ([`Technique::needs`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Data {
    /// Leaf priority lists (spec §6.11; `build --prune`).
    PriorityLists,
    /// Impostor planes and their atlas (spec §6.10; `build --impostors`).
    Planes,
    /// Leaf ellipsoids, with or without branch lines for the bark (spec §6.8, §6.9;
    /// `build --ellipsoids --lines`).
    Ellipsoids,
    /// The baseline LoD chain (spec §6.12; `build --baselines`).
    LodChain,
    /// The baseline billboards (spec §6.13; `build --baselines`).
    Billboards,
}

impl Data {
    /// What it is, for messages ("this container holds no …").
    #[must_use]
    pub const fn description(self) -> &'static str {
        match self {
            Self::PriorityLists => "pruning priority lists (build with --prune)",
            Self::Planes => "impostor planes (build with --impostors)",
            Self::Ellipsoids => "ellipsoids (build with --ellipsoids, and --lines for the bark)",
            Self::LodChain => "baseline LoD chain (build with --baselines)",
            Self::Billboards => "baseline billboards (build with --baselines)",
        }
    }
}

/// A kind of primitive a technique submits: what the frame statistics, the calibration tables
/// and the reports count, each one primitive (a splat, a plane, a quad, an ellipsoid's and a
/// line's bounding quad are each one).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Primitive {
    /// Triangles: bark, leaves, pruned leaves, LoD chain levels.
    Triangle,
    /// Points of the sequential point tree, drawn as splats.
    Point,
    /// Impostor planes.
    Plane,
    /// Baseline billboard quads (facing or crossed).
    Billboard,
    /// Clasen's leaf ellipsoids.
    Ellipsoid,
    /// Clasen's branch lines.
    Line,
}

impl Primitive {
    /// Every kind, in the order tables list them.
    pub const ALL: [Self; 6] = [Self::Triangle, Self::Point, Self::Plane, Self::Billboard, Self::Ellipsoid, Self::Line];

    /// How many kinds there are: the length of per-kind arrays.
    pub const COUNT: usize = Self::ALL.len();

    /// The kind's index in [`Self::ALL`] (and in per-kind arrays).
    #[must_use]
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The kind's plural name, as tables print it.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Triangle => "triangles",
            Self::Point => "points",
            Self::Plane => "planes",
            Self::Billboard => "billboards",
            Self::Ellipsoid => "ellipsoids",
            Self::Line => "lines",
        }
    }
}

/// Defines an array with one value per member of a list (`$key`, with `ALL`, `COUNT` and
/// `index`), indexed by the member.
macro_rules! per_key {
    ($(#[$doc:meta])* $name:ident, $key:ident, $what:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
        pub struct $name<T>(pub [T; $key::COUNT]);

        impl<T: Copy> $name<T> {
            #[doc = concat!("The value of `", $what, "`.")]
            #[must_use]
            pub fn get(&self, key: $key) -> T {
                self.0[key.index()]
            }

            #[doc = concat!("The value of `", $what, "`, to change.")]
            pub fn get_mut(&mut self, key: $key) -> &mut T {
                &mut self.0[key.index()]
            }

            #[doc = concat!("Each ", $what, " with its value.")]
            pub fn iter(&self) -> impl Iterator<Item = ($key, T)> + '_ {
                $key::ALL.into_iter().zip(self.0.iter().copied())
            }
        }

        impl<T> std::ops::Index<$key> for $name<T> {
            type Output = T;

            fn index(&self, key: $key) -> &T {
                &self.0[key.index()]
            }
        }

        impl<T> std::ops::IndexMut<$key> for $name<T> {
            fn index_mut(&mut self, key: $key) -> &mut T {
                &mut self.0[key.index()]
            }
        }

        impl<T: Copy + std::ops::AddAssign> std::ops::AddAssign for $name<T> {
            fn add_assign(&mut self, other: Self) {
                for (a, b) in self.0.iter_mut().zip(other.0) {
                    *a += b;
                }
            }
        }

        impl<T: Copy + std::iter::Sum<T>> $name<T> {
            #[doc = concat!("The sum over every ", $what, ".")]
            #[must_use]
            pub fn total(&self) -> T {
                self.0.iter().copied().sum()
            }
        }
    };
}

per_key!(
    /// A value per technique (a count, or a list such as an [`Assignment`](crate::Assignment)),
    /// indexed by [`Technique::index`] or by the technique itself.
    PerTechnique,
    Technique,
    "technique"
);

per_key!(
    /// A value per kind of primitive (a count), indexed by [`Primitive::index`] or by the kind
    /// itself.
    PerPrimitive,
    Primitive,
    "kind"
);

impl PerTechnique<usize> {
    /// How many of `containers` hold each technique's data ([`Technique::held_by`]).
    #[must_use]
    pub fn held_by<'a>(containers: impl IntoIterator<Item = &'a Container>) -> Self {
        let mut held = Self::default();
        for container in containers {
            for technique in Technique::ALL {
                *held.get_mut(technique) += usize::from(technique.held_by(container));
            }
        }
        held
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_indices_follow_the_list() {
        for (i, t) in Technique::ALL.into_iter().enumerate() {
            assert_eq!(t.index(), i);
            assert_eq!(Technique::from_name(t.name()), Some(t));
            assert_eq!(t.to_string(), t.name());
        }
        assert_eq!(Technique::from_name("policy"), None);
        let names: std::collections::BTreeSet<_> = Technique::ALL.iter().map(|t| t.name()).collect();
        assert_eq!(names.len(), Technique::COUNT, "names are distinct");
    }

    #[test]
    fn only_the_full_mesh_and_the_point_tree_need_no_optional_data() {
        for t in Technique::ALL {
            assert_eq!(t.needs().is_none(), matches!(t, Technique::Full | Technique::Spt), "{t}");
        }
        assert_eq!(Technique::FALLBACK.needs(), None);
    }

    #[test]
    fn per_technique_counts_add_and_total() {
        let mut a = PerTechnique::<u32>::default();
        *a.get_mut(Technique::Impostors) += 2;
        let mut b = PerTechnique::<u32>::default();
        *b.get_mut(Technique::Impostors) += 1;
        *b.get_mut(Technique::Spt) += 5;
        a += b;
        assert_eq!((a.get(Technique::Impostors), a.get(Technique::Spt), a.total()), (3, 5, 8));
        assert_eq!(a.iter().filter(|&(_, n)| n > 0).count(), 2);
    }
}
