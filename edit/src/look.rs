//! The choice of how an edit goes back into its photo: the composite ([`crate::composite`]) and
//! the range it is held to ([`crate::range`]), each the one measured best for what is known
//! where not asked for.

use crate::range::Range;

/// How the re-rendered object goes back into the photo: the composite, and the range the edit
/// is held to. A composite alone holds the edit to the photo's range (the default).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Look {
    /// How O' goes back into the photo.
    pub composite: crate::Composite,
    /// How the relit render goes back (`--relight`).
    pub relit: crate::Composite,
    /// What the edited object's level is held to.
    pub range: Range,
}

impl Look {
    /// The composite and range asked for, each where not given the one measured best
    /// ([`crate::Composite::best_for`], [`Range::best_for`]) for an object whose own material is
    /// `known` or not, under the network's light.
    pub fn chosen(composite: Option<crate::Composite>, range: Option<Range>, known: bool) -> Self {
        Self::for_known(composite, range, known, false)
    }

    /// As [`Look::chosen`], with the light known too (a given map at a known level): the edit's
    /// composite follows both, its range either, and a relit image is `ratio`'s unless a
    /// composite is asked for ([`crate::Composite::best_for_relighting`]).
    pub fn for_known(
        composite: Option<crate::Composite>,
        range: Option<Range>,
        known_material: bool,
        known_light: bool,
    ) -> Self {
        Self {
            composite: composite.unwrap_or(crate::Composite::best_for(known_material, known_light)),
            relit: composite.unwrap_or(crate::Composite::best_for_relighting()),
            range: range.unwrap_or(Range::best_for(known_material || known_light)),
        }
    }
}

impl From<crate::Composite> for Look {
    /// The composite with the photo's range: the network's level (a known material picks its
    /// range with [`Range::best_for`]).
    fn from(composite: crate::Composite) -> Self {
        Self {
            composite,
            relit: composite,
            range: Range::Photo,
        }
    }
}
