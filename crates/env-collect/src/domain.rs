//! The fixed vocabulary of the domain: object categories, drop-off
//! receptacles, search-location surfaces, and the actions over them.

use std::fmt;
use std::sync::LazyLock;

use ctg_graph::{ActionId, Vocabulary};
use serde::{Deserialize, Serialize};

/// Number of object categories (C in the paper).
pub const NUM_CATEGORIES: usize = 8;
/// Number of drop-off receptacles (K in the paper).
pub const NUM_RECEPTACLES: usize = 5;
/// Fewest target objects in a task.
pub const MIN_OBJECTS: usize = 1;
/// Most target objects in a task. The figures test N = 1..=5 (the paper's);
/// 6 exists for validation on demos longer than any test episode's.
pub const MAX_OBJECTS: usize = 6;
/// Search locations beyond the number of targets: M = N + 3.
pub const EXTRA_LOCATIONS: usize = 3;

/// A pickupable object category (AI2-THOR kitchen types).
///
/// Each has its own shape and colour signature in the rendered frame (see
/// [`crate::render`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Category {
    /// A red disc with a stem and a leaf.
    Apple,
    /// A brown loaf with scored crust.
    Bread,
    /// A cream egg shape, narrower at the top.
    Egg,
    /// A green disc of concentric leaf rings.
    Lettuce,
    /// A blue mug body with a ring handle.
    Mug,
    /// A tan flat ellipse with dark eyes.
    Potato,
    /// A long silver blade with a black handle.
    Knife,
    /// A yellow half-disc bowl with a rim.
    Bowl,
}

impl Category {
    /// Every category, in index order.
    pub const ALL: [Category; NUM_CATEGORIES] = [
        Category::Apple,
        Category::Bread,
        Category::Egg,
        Category::Lettuce,
        Category::Mug,
        Category::Potato,
        Category::Knife,
        Category::Bowl,
    ];

    /// Position in [`Category::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The category with this index, if any.
    pub fn from_index(index: usize) -> Option<Category> {
        Self::ALL.get(index).copied()
    }

    /// The AI2-THOR type name, e.g. `Apple`.
    pub fn name(self) -> &'static str {
        match self {
            Category::Apple => "Apple",
            Category::Bread => "Bread",
            Category::Egg => "Egg",
            Category::Lettuce => "Lettuce",
            Category::Mug => "Mug",
            Category::Potato => "Potato",
            Category::Knife => "Knife",
            Category::Bowl => "Bowl",
        }
    }

    /// The category called `name` (exact, case-sensitive), if any.
    pub fn from_name(name: &str) -> Option<Category> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }
}

impl fmt::Display for Category {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A drop-off receptacle (AI2-THOR receptacle types).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Receptacle {
    /// A white fridge, open, with a light-blue interior.
    Fridge,
    /// A steel counter with a dark basin.
    Sink,
    /// A dark wooden cabinet, open.
    Cabinet,
    /// A black microwave with a lit yellow window.
    Microwave,
    /// A green bin.
    GarbageCan,
}

impl Receptacle {
    /// Every receptacle, in index order.
    pub const ALL: [Receptacle; NUM_RECEPTACLES] = [
        Receptacle::Fridge,
        Receptacle::Sink,
        Receptacle::Cabinet,
        Receptacle::Microwave,
        Receptacle::GarbageCan,
    ];

    /// Position in [`Receptacle::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The receptacle with this index, if any.
    pub fn from_index(index: usize) -> Option<Receptacle> {
        Self::ALL.get(index).copied()
    }

    /// The AI2-THOR type name, e.g. `Fridge`.
    pub fn name(self) -> &'static str {
        match self {
            Receptacle::Fridge => "Fridge",
            Receptacle::Sink => "Sink",
            Receptacle::Cabinet => "Cabinet",
            Receptacle::Microwave => "Microwave",
            Receptacle::GarbageCan => "GarbageCan",
        }
    }

    /// The receptacle called `name` (exact, case-sensitive), if any.
    pub fn from_name(name: &str) -> Option<Receptacle> {
        Self::ALL.into_iter().find(|r| r.name() == name)
    }
}

impl fmt::Display for Receptacle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The kind of surface a search location is (only its look depends on it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Surface {
    /// Light grey speckled granite.
    CounterTop,
    /// Brown wooden planks.
    TableTop,
    /// Beige shelf boards.
    Shelf,
    /// A lilac checked table cloth.
    DiningTable,
    /// A dark drawer interior in a light wooden frame.
    Drawer,
}

impl Surface {
    /// Every surface kind.
    pub const ALL: [Surface; 5] = [
        Surface::CounterTop,
        Surface::TableTop,
        Surface::Shelf,
        Surface::DiningTable,
        Surface::Drawer,
    ];
}

/// One action of the domain, the typed form of an [`ActionId`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Action {
    /// Go to the next search location (in the episode's random order,
    /// cyclically).
    Search,
    /// Pick up an object of this category visible at the current place;
    /// fails if none is visible or the hand is full.
    Pickup(Category),
    /// Go to this receptacle and put the held object in it; fails (after
    /// going there) if the hand is empty.
    Dropoff(Receptacle),
}

/// Index of the first `pickup` action in the vocabulary.
const PICKUP_BASE: usize = 3;
/// Index of the first `dropoff` action in the vocabulary.
const DROPOFF_BASE: usize = PICKUP_BASE + NUM_CATEGORIES;

impl Action {
    /// Every action, in vocabulary order.
    pub fn all() -> impl Iterator<Item = Action> {
        std::iter::once(Action::Search)
            .chain(Category::ALL.into_iter().map(Action::Pickup))
            .chain(Receptacle::ALL.into_iter().map(Action::Dropoff))
    }

    /// The vocabulary id of this action.
    pub fn id(self) -> ActionId {
        ActionId::new(match self {
            Action::Search => 2,
            Action::Pickup(c) => PICKUP_BASE + c.index(),
            Action::Dropoff(r) => DROPOFF_BASE + r.index(),
        })
    }

    /// The action with this id; `None` for `<start>`, `<end>` and ids out of
    /// range.
    pub fn from_id(id: ActionId) -> Option<Action> {
        let i = id.index();
        match i {
            2 => Some(Action::Search),
            _ if (PICKUP_BASE..DROPOFF_BASE).contains(&i) => {
                Category::from_index(i - PICKUP_BASE).map(Action::Pickup)
            }
            _ if i >= DROPOFF_BASE => Receptacle::from_index(i - DROPOFF_BASE).map(Action::Dropoff),
            _ => None,
        }
    }

    /// The vocabulary name, e.g. `pickup(Apple)`.
    pub fn name(self) -> String {
        match self {
            Action::Search => "search".to_owned(),
            Action::Pickup(c) => format!("pickup({c})"),
            Action::Dropoff(r) => format!("dropoff({r})"),
        }
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

static VOCABULARY: LazyLock<Vocabulary> = LazyLock::new(|| {
    Vocabulary::new(Action::all().map(Action::name))
        .expect("the built-in action names are unique, non-empty and not reserved")
});

/// The domain's vocabulary: `<start>`, `<end>`, `search`, the eight
/// `pickup(category)` and the five `dropoff(receptacle)` actions (16 nodes),
/// the same for every task.
pub fn vocabulary() -> &'static Vocabulary {
    &VOCABULARY
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn action_ids_round_trip_through_the_vocabulary() {
        let vocab = vocabulary();
        assert_eq!(vocab.len(), 2 + 1 + NUM_CATEGORIES + NUM_RECEPTACLES);
        for action in Action::all() {
            let id = action.id();
            assert_eq!(vocab.name(id), Some(action.name().as_str()));
            assert_eq!(Action::from_id(id), Some(action));
            assert_eq!(vocab.id(&action.name()), Some(id));
        }
        assert_eq!(Action::from_id(Vocabulary::START), None);
        assert_eq!(Action::from_id(Vocabulary::END), None);
        assert_eq!(Action::from_id(ActionId::new(vocab.len())), None);
    }

    #[test]
    fn names_round_trip() {
        for c in Category::ALL {
            assert_eq!(Category::from_name(c.name()), Some(c));
            assert_eq!(Category::from_index(c.index()), Some(c));
        }
        for r in Receptacle::ALL {
            assert_eq!(Receptacle::from_name(r.name()), Some(r));
            assert_eq!(Receptacle::from_index(r.index()), Some(r));
        }
        assert_eq!(Category::from_name("apple"), None);
    }
}
