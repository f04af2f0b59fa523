//! Gestures (G1–G15), tasks, skill levels, trial ids, and the NTG vocabulary.

use std::fmt;
use std::str::FromStr;

use ctg_graph::{ActionId, Vocabulary};

/// One of the fifteen JIGSAWS surgical gestures, `G1` to `G15`.
///
/// In the NTG vocabulary of [`gesture_vocabulary`], gesture `Gk` has the
/// action id `k + 1` (ids 0 and 1 are `<start>` and `<end>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Gesture(u8);

const GESTURE_NAMES: [&str; 15] = [
    "G1", "G2", "G3", "G4", "G5", "G6", "G7", "G8", "G9", "G10", "G11", "G12", "G13", "G14", "G15",
];

const GESTURE_DESCRIPTIONS: [&str; 15] = [
    "reaching for needle with right hand",
    "positioning needle",
    "pushing needle through tissue",
    "transferring needle from left to right",
    "moving to center with needle in grip",
    "pulling suture with left hand",
    "pulling suture with right hand",
    "orienting needle",
    "using right hand to help tighten suture",
    "loosening more suture",
    "dropping suture at end and moving to end points",
    "reaching for needle with left hand",
    "making C loop around right hand",
    "reaching for suture with right hand",
    "pulling suture with both hands",
];

#[allow(missing_docs)] // G1 ... G15 are documented by `Gesture::description`
impl Gesture {
    pub const G1: Gesture = Gesture(1);
    pub const G2: Gesture = Gesture(2);
    pub const G3: Gesture = Gesture(3);
    pub const G4: Gesture = Gesture(4);
    pub const G5: Gesture = Gesture(5);
    pub const G6: Gesture = Gesture(6);
    pub const G7: Gesture = Gesture(7);
    pub const G8: Gesture = Gesture(8);
    pub const G9: Gesture = Gesture(9);
    pub const G10: Gesture = Gesture(10);
    pub const G11: Gesture = Gesture(11);
    pub const G12: Gesture = Gesture(12);
    pub const G13: Gesture = Gesture(13);
    pub const G14: Gesture = Gesture(14);
    pub const G15: Gesture = Gesture(15);
}

impl Gesture {
    /// Number of gestures in the JIGSAWS vocabulary.
    pub const COUNT: usize = 15;

    /// Gesture `Gk` for `k` in `1..=15`.
    pub fn new(k: u8) -> Option<Gesture> {
        (1..=15).contains(&k).then_some(Gesture(k))
    }

    /// The `k` of `Gk` (1 to 15).
    pub fn number(self) -> u8 {
        self.0
    }

    /// Every gesture, `G1` first.
    pub fn all() -> impl Iterator<Item = Gesture> {
        (1..=15).map(Gesture)
    }

    /// The label as written in transcriptions, e.g. `"G8"`.
    pub fn name(self) -> &'static str {
        GESTURE_NAMES[usize::from(self.0 - 1)]
    }

    /// The JIGSAWS description, e.g. `"orienting needle"` for `G8`.
    pub fn description(self) -> &'static str {
        GESTURE_DESCRIPTIONS[usize::from(self.0 - 1)]
    }

    /// Parses a transcription label (`"G1"` to `"G15"`, exactly).
    pub fn parse(token: &str) -> Option<Gesture> {
        GESTURE_NAMES
            .iter()
            .position(|&n| n == token)
            .map(|i| Gesture(i as u8 + 1))
    }

    /// This gesture's node in [`gesture_vocabulary`].
    pub fn action_id(self) -> ActionId {
        ActionId::new(usize::from(self.0) + 1)
    }

    /// The gesture of a node of [`gesture_vocabulary`] (`None` for
    /// `<start>`, `<end>` and out-of-range ids).
    pub fn from_action_id(id: ActionId) -> Option<Gesture> {
        let k = id.index().checked_sub(1)?;
        u8::try_from(k).ok().and_then(Gesture::new)
    }
}

impl fmt::Display for Gesture {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl serde::Serialize for Gesture {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Gesture {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Gesture::parse(&s).ok_or_else(|| serde::de::Error::custom(format!("unknown gesture `{s}`")))
    }
}

/// The NTG action vocabulary of JIGSAWS: `<start>`, `<end>`, then `G1` to
/// `G15` in order, so that `Gk` has id `k + 1` (see [`Gesture::action_id`]).
/// All fifteen are included even though `G7` never occurs, so every task
/// shares one vocabulary.
pub fn gesture_vocabulary() -> Vocabulary {
    Vocabulary::new(GESTURE_NAMES).expect("fifteen distinct non-reserved names")
}

/// The three JIGSAWS tasks (serialised by folder name, e.g. `Knot_Tying`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub enum Task {
    /// Suturing: needle throws through a tissue pad.
    Suturing,
    /// Needle Passing: needle throws through four small rings.
    #[serde(rename = "Needle_Passing")]
    NeedlePassing,
    /// Knot Tying: a knot tied with the suture.
    #[serde(rename = "Knot_Tying")]
    KnotTying,
}

impl Task {
    /// All three tasks, in the order the dataset lists them.
    pub const ALL: [Task; 3] = [Task::Suturing, Task::NeedlePassing, Task::KnotTying];

    /// The folder and file-name prefix: `Suturing`, `Needle_Passing`,
    /// `Knot_Tying`.
    pub fn folder_name(self) -> &'static str {
        match self {
            Task::Suturing => "Suturing",
            Task::NeedlePassing => "Needle_Passing",
            Task::KnotTying => "Knot_Tying",
        }
    }

    /// The task whose folder name is `name`.
    pub fn from_folder_name(name: &str) -> Option<Task> {
        Task::ALL.into_iter().find(|t| t.folder_name() == name)
    }

    /// The gestures that occur in this task's transcriptions (DATA.md),
    /// in order of number.
    pub fn gestures(self) -> &'static [Gesture] {
        use Gesture as G;
        match self {
            Task::Suturing => &[
                G::G1,
                G::G2,
                G::G3,
                G::G4,
                G::G5,
                G::G6,
                G::G8,
                G::G9,
                G::G10,
                G::G11,
            ],
            Task::NeedlePassing => &[G::G1, G::G2, G::G3, G::G4, G::G5, G::G6, G::G8, G::G11],
            Task::KnotTying => &[G::G1, G::G11, G::G12, G::G13, G::G14, G::G15],
        }
    }

    /// The trials of the real dataset's inventory: `(surgeon, trial number)`
    /// pairs with a transcription, kinematics and a meta row. Suturing has 39,
    /// Needle Passing 28, Knot Tying 36. (Suturing `H002` has kinematics but
    /// no transcription; it is not listed here, see
    /// [`Task::kinematics_only_trials`].)
    pub fn inventory(self) -> Vec<(char, u16)> {
        let missing: &[(char, u16)] = match self {
            Task::Suturing => &[('H', 2)],
            Task::NeedlePassing => &[
                ('B', 5),
                ('E', 2),
                ('F', 2),
                ('F', 5),
                ('G', 1),
                ('G', 2),
                ('G', 3),
                ('G', 4),
                ('G', 5),
                ('H', 1),
                ('H', 3),
                ('I', 1),
            ],
            Task::KnotTying => &[('B', 5), ('H', 1), ('H', 2), ('I', 4)],
        };
        ('B'..='I')
            .flat_map(|s| (1..=5).map(move |n| (s, n)))
            .filter(|p| !missing.contains(p))
            .collect()
    }

    /// Trials of the real dataset that have a kinematics file but no
    /// transcription (Suturing `H002`).
    pub fn kinematics_only_trials(self) -> &'static [(char, u16)] {
        match self {
            Task::Suturing => &[('H', 2)],
            _ => &[],
        }
    }
}

impl fmt::Display for Task {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.folder_name())
    }
}

impl FromStr for Task {
    type Err = String;
    /// Accepts the folder name (`Knot_Tying`) or a lower-case, hyphen or
    /// underscore form (`knot-tying`, `knot_tying`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.to_ascii_lowercase().replace('-', "_");
        Task::ALL
            .into_iter()
            .find(|t| t.folder_name().to_ascii_lowercase() == norm)
            .ok_or_else(|| {
                format!("unknown task `{s}` (expected Suturing, Needle_Passing or Knot_Tying)")
            })
    }
}

/// Self-rated skill level from the meta file.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub enum Skill {
    /// `N`: fewer than 10 hours of robotic surgery.
    Novice,
    /// `I`: 10 to 100 hours.
    Intermediate,
    /// `E`: more than 100 hours.
    Expert,
}

impl Skill {
    /// The meta-file letter: `N`, `I` or `E`.
    pub fn letter(self) -> char {
        match self {
            Skill::Novice => 'N',
            Skill::Intermediate => 'I',
            Skill::Expert => 'E',
        }
    }

    /// Parses the meta-file letter.
    pub fn parse(token: &str) -> Option<Skill> {
        match token {
            "N" => Some(Skill::Novice),
            "I" => Some(Skill::Intermediate),
            "E" => Some(Skill::Expert),
            _ => None,
        }
    }

    /// The self-rated level of the real dataset's surgeons: D and E expert,
    /// C and F intermediate, B, G, H and I novice (`None` for other letters).
    pub fn of_surgeon(surgeon: char) -> Option<Skill> {
        match surgeon {
            'D' | 'E' => Some(Skill::Expert),
            'C' | 'F' => Some(Skill::Intermediate),
            'B' | 'G' | 'H' | 'I' => Some(Skill::Novice),
            _ => None,
        }
    }
}

/// A trial id, `<Task>_<Surgeon><NNN>`, e.g. `Knot_Tying_B001`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub struct TrialId {
    /// The task.
    pub task: Task,
    /// The surgeon's letter (`B` to `I` in the real dataset).
    pub surgeon: char,
    /// The trial number (1 to 5 in the real dataset), written with three
    /// digits.
    pub number: u16,
}

impl TrialId {
    /// A trial id.
    pub fn new(task: Task, surgeon: char, number: u16) -> TrialId {
        TrialId {
            task,
            surgeon,
            number,
        }
    }

    /// Parses `<Task>_<Surgeon><NNN>`: the task is everything before the
    /// last `_` (task names contain underscores), the surgeon one ASCII
    /// upper-case letter and the number exactly three digits.
    pub fn parse(text: &str) -> Option<TrialId> {
        let (task, last) = text.rsplit_once('_')?;
        let task = Task::from_folder_name(task)?;
        let mut chars = last.chars();
        let surgeon = chars.next().filter(char::is_ascii_uppercase)?;
        let digits = chars.as_str();
        if digits.len() != 3 || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        Some(TrialId::new(task, surgeon, digits.parse().ok()?))
    }
}

impl fmt::Display for TrialId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}_{}{:03}", self.task, self.surgeon, self.number)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gesture_names_round_trip_and_ids_line_up() {
        let vocab = gesture_vocabulary();
        assert_eq!(vocab.len(), 17);
        for g in Gesture::all() {
            assert_eq!(Gesture::parse(g.name()), Some(g));
            assert_eq!(vocab.id(g.name()), Some(g.action_id()));
            assert_eq!(Gesture::from_action_id(g.action_id()), Some(g));
        }
        assert_eq!(Gesture::from_action_id(Vocabulary::START), None);
        assert_eq!(Gesture::from_action_id(Vocabulary::END), None);
        assert_eq!(Gesture::from_action_id(ActionId::new(17)), None);
        for bad in ["G0", "G16", "g1", "G01", "", "G"] {
            assert_eq!(Gesture::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn trial_ids_with_underscored_tasks() {
        let id = TrialId::parse("Knot_Tying_B001").unwrap();
        assert_eq!(id, TrialId::new(Task::KnotTying, 'B', 1));
        assert_eq!(id.to_string(), "Knot_Tying_B001");
        let id = TrialId::parse("Needle_Passing_H004").unwrap();
        assert_eq!(id.task, Task::NeedlePassing);
        for bad in [
            "Knot_Tying",
            "Knot_Tying_b001",
            "Knot_Tying_B01",
            "Knot_Tying_B0001",
            "Knot_B001",
            "Suturing_B00x",
            "_B001",
        ] {
            assert_eq!(TrialId::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn inventory_counts_match_the_real_dataset() {
        assert_eq!(Task::Suturing.inventory().len(), 39);
        assert_eq!(Task::NeedlePassing.inventory().len(), 28);
        assert_eq!(Task::KnotTying.inventory().len(), 36);
    }

    #[test]
    fn needle_passing_gestures_are_a_subset_of_suturing() {
        let np = Task::NeedlePassing.gestures();
        assert!(np.iter().all(|g| Task::Suturing.gestures().contains(g)));
        let shared: Vec<_> = np
            .iter()
            .filter(|g| Task::KnotTying.gestures().contains(g))
            .collect();
        assert_eq!(shared, [&Gesture::G1, &Gesture::G11]);
        assert!(
            Task::ALL
                .iter()
                .all(|t| !t.gestures().contains(&Gesture::G7))
        );
    }

    #[test]
    fn task_from_str_is_lenient_about_case() {
        assert_eq!("knot-tying".parse::<Task>(), Ok(Task::KnotTying));
        assert_eq!("Needle_Passing".parse::<Task>(), Ok(Task::NeedlePassing));
        assert!("knots".parse::<Task>().is_err());
    }
}
