//! Action vocabularies and action ids.

use std::collections::HashMap;
use std::fmt;

use crate::{CtgError, Result};

/// Index of an action (a CTG node) in a [`Vocabulary`].
///
/// Ids `0` and `1` are always [`Vocabulary::START`] and [`Vocabulary::END`];
/// real actions start at `2`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(transparent))]
pub struct ActionId(usize);

impl ActionId {
    /// The id with the given index. Validity is checked where the id is used
    /// (against a vocabulary or a graph), never assumed.
    pub const fn new(index: usize) -> Self {
        ActionId(index)
    }

    /// The position of this action in its vocabulary and of its row in
    /// adjacency matrices.
    pub const fn index(self) -> usize {
        self.0
    }
}

impl fmt::Display for ActionId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "#{}", self.0)
    }
}

/// The fixed, ordered action set of a domain: every node a CTG over this
/// domain can have.
///
/// Two reserved nodes come first, `<start>` (id 0) and `<end>` (id 1); the
/// domain's actions follow in the order given. Names are unique and non-empty.
///
/// ```
/// use ctg_graph::Vocabulary;
/// let vocab = Vocabulary::new(["pick", "place"]).unwrap();
/// assert_eq!(vocab.len(), 4); // <start>, <end>, pick, place
/// let pick = vocab.id("pick").unwrap();
/// assert_eq!(vocab.name(pick), Some("pick"));
/// assert_eq!(vocab.name(Vocabulary::END), Some("<end>"));
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(
    feature = "serde",
    serde(try_from = "Vec<String>", into = "Vec<String>")
)]
pub struct Vocabulary {
    names: Vec<String>,
    index: HashMap<String, ActionId>,
}

impl Vocabulary {
    /// The reserved node every task graph starts from.
    pub const START: ActionId = ActionId(0);
    /// The reserved node that ends every task; choosing it ends an episode.
    pub const END: ActionId = ActionId(1);
    /// Display name of [`Vocabulary::START`].
    pub const START_NAME: &'static str = "<start>";
    /// Display name of [`Vocabulary::END`].
    pub const END_NAME: &'static str = "<end>";

    /// A vocabulary of the given actions, in order, after `<start>` and `<end>`.
    ///
    /// Errors on an empty name, a duplicate, or a reserved name.
    pub fn new<I, S>(actions: I) -> Result<Self>
    where
        I: IntoIterator<Item = S>,
        S: Into<String>,
    {
        let mut names = vec![Self::START_NAME.to_owned(), Self::END_NAME.to_owned()];
        let mut index = HashMap::new();
        index.insert(Self::START_NAME.to_owned(), Self::START);
        index.insert(Self::END_NAME.to_owned(), Self::END);
        for action in actions {
            let name: String = action.into();
            if name.trim().is_empty() {
                return Err(CtgError::EmptyActionName);
            }
            if name == Self::START_NAME || name == Self::END_NAME {
                return Err(CtgError::ReservedName(name));
            }
            if index.contains_key(&name) {
                return Err(CtgError::DuplicateAction(name));
            }
            index.insert(name.clone(), ActionId(names.len()));
            names.push(name);
        }
        Ok(Vocabulary { names, index })
    }

    /// The vocabulary of every action appearing in `sequences`, in order of
    /// first appearance. Reserved names are rejected.
    ///
    /// ```
    /// use ctg_graph::Vocabulary;
    /// let vocab = Vocabulary::from_sequences([["a", "b"], ["b", "c"]]).unwrap();
    /// assert_eq!(vocab.action_names().collect::<Vec<_>>(), ["a", "b", "c"]);
    /// ```
    pub fn from_sequences<I, J, S>(sequences: I) -> Result<Self>
    where
        I: IntoIterator<Item = J>,
        J: IntoIterator<Item = S>,
        S: AsRef<str>,
    {
        let mut seen: Vec<String> = Vec::new();
        for sequence in sequences {
            for action in sequence {
                let action = action.as_ref();
                if !seen.iter().any(|s| s == action) {
                    seen.push(action.to_owned());
                }
            }
        }
        Self::new(seen)
    }

    /// Number of nodes, the two reserved ones included.
    #[allow(clippy::len_without_is_empty)] // never empty: <start> and <end> always exist
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Number of real (non-reserved) actions.
    pub fn num_actions(&self) -> usize {
        self.names.len() - 2
    }

    /// The id of the action called `name`, if any.
    pub fn id(&self, name: &str) -> Option<ActionId> {
        self.index.get(name).copied()
    }

    /// Like [`Vocabulary::id`], but an unknown name is an error.
    pub fn parse(&self, name: &str) -> Result<ActionId> {
        self.id(name)
            .ok_or_else(|| CtgError::UnknownAction(name.to_owned()))
    }

    /// Parses a whitespace-separated action sequence such as `"pick place"`.
    /// Reserved names are rejected: they are never part of a demonstrated path.
    pub fn parse_sequence(&self, text: &str) -> Result<Vec<ActionId>> {
        text.split_whitespace()
            .map(|name| {
                let id = self.parse(name)?;
                self.check_action(id)?;
                Ok(id)
            })
            .collect()
    }

    /// The name of `id`, or `None` if it is out of range.
    pub fn name(&self, id: ActionId) -> Option<&str> {
        self.names.get(id.0).map(String::as_str)
    }

    /// All node names, reserved ones first.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Names of the real actions, in order.
    pub fn action_names(&self) -> impl Iterator<Item = &str> + '_ {
        self.names[2..].iter().map(String::as_str)
    }

    /// Ids of every node, reserved ones first.
    pub fn ids(&self) -> impl Iterator<Item = ActionId> + use<> {
        (0..self.names.len()).map(ActionId)
    }

    /// Ids of the real actions (everything but `<start>` and `<end>`).
    pub fn actions(&self) -> impl Iterator<Item = ActionId> + use<> {
        (2..self.names.len()).map(ActionId)
    }

    /// Whether `id` is `<start>` or `<end>`.
    pub fn is_reserved(id: ActionId) -> bool {
        id == Self::START || id == Self::END
    }

    /// Ok if `id` is any node of this vocabulary.
    pub fn check(&self, id: ActionId) -> Result<()> {
        if id.0 < self.names.len() {
            Ok(())
        } else {
            Err(CtgError::ActionOutOfRange {
                id: id.0,
                len: self.names.len(),
            })
        }
    }

    /// Ok if `id` is a real action of this vocabulary (not reserved).
    pub fn check_action(&self, id: ActionId) -> Result<()> {
        self.check(id)?;
        match id {
            Self::START => Err(CtgError::ReservedAction(Self::START_NAME)),
            Self::END => Err(CtgError::ReservedAction(Self::END_NAME)),
            _ => Ok(()),
        }
    }

    /// Names of a sequence of ids, joined by spaces (out-of-range ids print
    /// as `#i`).
    pub fn format_sequence(&self, ids: &[ActionId]) -> String {
        ids.iter()
            .map(|&id| self.name(id).map_or_else(|| id.to_string(), str::to_owned))
            .collect::<Vec<_>>()
            .join(" ")
    }
}

impl TryFrom<Vec<String>> for Vocabulary {
    type Error = CtgError;
    /// Builds from the real action names (reserved ones excluded), as
    /// serialised by `From<Vocabulary> for Vec<String>`.
    fn try_from(actions: Vec<String>) -> Result<Self> {
        Vocabulary::new(actions)
    }
}

impl From<Vocabulary> for Vec<String> {
    /// The real action names, in order (the reserved nodes are implicit).
    fn from(vocab: Vocabulary) -> Self {
        vocab.names.into_iter().skip(2).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reserved_nodes_come_first() {
        let v = Vocabulary::new(["a"]).unwrap();
        assert_eq!(v.name(Vocabulary::START), Some("<start>"));
        assert_eq!(v.name(Vocabulary::END), Some("<end>"));
        assert_eq!(v.id("a"), Some(ActionId::new(2)));
        assert_eq!(v.actions().collect::<Vec<_>>(), [ActionId::new(2)]);
    }

    #[test]
    fn rejects_bad_names() {
        assert_eq!(
            Vocabulary::new(["a", "a"]),
            Err(CtgError::DuplicateAction("a".into()))
        );
        assert_eq!(Vocabulary::new([" "]), Err(CtgError::EmptyActionName));
        assert_eq!(
            Vocabulary::new(["<end>"]),
            Err(CtgError::ReservedName("<end>".into()))
        );
    }

    #[test]
    fn parse_sequence_rejects_unknown_and_reserved() {
        let v = Vocabulary::new(["a", "b"]).unwrap();
        assert_eq!(
            v.parse_sequence("a b a").unwrap(),
            [ActionId(2), ActionId(3), ActionId(2)]
        );
        assert_eq!(
            v.parse_sequence("a c"),
            Err(CtgError::UnknownAction("c".into()))
        );
        assert_eq!(
            v.parse_sequence("<start> a"),
            Err(CtgError::ReservedAction("<start>"))
        );
    }

    #[test]
    fn check_reports_out_of_range() {
        let v = Vocabulary::new(["a"]).unwrap();
        assert!(v.check(ActionId(2)).is_ok());
        assert_eq!(
            v.check(ActionId(3)),
            Err(CtgError::ActionOutOfRange { id: 3, len: 3 })
        );
    }
}
