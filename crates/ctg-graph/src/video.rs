//! Demonstrations as videos: many frames per action.

use crate::{ActionId, CtgError, Demonstration, Result, Vocabulary};

/// A demonstration recorded as a video: the flat action sequence, and the
/// frames seen along the way, several per action and of varying number.
///
/// The frames fall into `actions.len() + 1` consecutive, non-empty
/// *segments*: segment 0 is what is seen before the first action (its
/// label is `<start>`), segment `i + 1` is the motion of `actions[i]` (its
/// label is that action). The last frame of a segment is the scene once
/// its action is done: those *keyframes* are exactly a [`Demonstration`]'s
/// observations ([`VideoDemonstration::keyframes`]).
///
/// Per frame, [`frame_labels`](VideoDemonstration::frame_labels) is the
/// action it belongs to (a node localizer's target) and
/// [`frame_next_actions`](VideoDemonstration::frame_next_actions) the action
/// that follows its segment (an edge classifier's target); the action
/// sequence is a demo interpreter's target.
///
/// Validated at construction: at least one action, every action a real
/// action of the vocabulary, and one non-empty segment per action plus
/// the first.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct VideoDemonstration<F> {
    frames: Vec<F>,
    /// Exclusive end (frame index) of each segment; strictly increasing,
    /// the last equal to `frames.len()`.
    segment_ends: Vec<usize>,
    actions: Vec<ActionId>,
}

impl<F> VideoDemonstration<F> {
    /// A validated video demonstration from its segments: `segments[0]` the
    /// frames before the first action, `segments[i + 1]` those of
    /// `actions[i]`.
    ///
    /// ```
    /// use ctg_graph::{VideoDemonstration, Vocabulary};
    /// let vocab = Vocabulary::new(["pick", "place"]).unwrap();
    /// let actions = vocab.parse_sequence("pick place").unwrap();
    /// let video = VideoDemonstration::from_segments(
    ///     vec![vec!['a'], vec!['b', 'c', 'd'], vec!['e', 'f']],
    ///     actions,
    ///     &vocab,
    /// )
    /// .unwrap();
    /// assert_eq!(video.num_frames(), 6);
    /// assert_eq!(video.keyframes().observations(), &['a', 'd', 'f']);
    /// ```
    pub fn from_segments(
        segments: Vec<Vec<F>>,
        actions: Vec<ActionId>,
        vocab: &Vocabulary,
    ) -> Result<Self> {
        let mut ends = Vec::with_capacity(segments.len());
        let mut frames = Vec::with_capacity(segments.iter().map(Vec::len).sum());
        for segment in segments {
            frames.extend(segment);
            ends.push(frames.len());
        }
        Self::new(frames, ends, actions, vocab)
    }

    /// A validated video demonstration from all its frames and the
    /// exclusive end of each segment (`segment_ends[s]` is one past the
    /// last frame of segment `s`).
    pub fn new(
        frames: Vec<F>,
        segment_ends: Vec<usize>,
        actions: Vec<ActionId>,
        vocab: &Vocabulary,
    ) -> Result<Self> {
        if actions.is_empty() {
            return Err(CtgError::EmptyDemonstration);
        }
        for &action in &actions {
            vocab.check_action(action)?;
        }
        let problem = |problem: String| CtgError::VideoSegments {
            actions: actions.len(),
            expected: actions.len() + 1,
            problem,
        };
        if segment_ends.len() != actions.len() + 1 {
            return Err(problem(format!("got {} segments", segment_ends.len())));
        }
        let mut start = 0;
        for (s, &end) in segment_ends.iter().enumerate() {
            if end <= start {
                return Err(problem(format!("segment {s} is empty")));
            }
            start = end;
        }
        if start != frames.len() {
            return Err(problem(format!(
                "the segments cover {start} frames, the video has {}",
                frames.len()
            )));
        }
        Ok(VideoDemonstration {
            frames,
            segment_ends,
            actions,
        })
    }

    /// Every frame, in order.
    pub fn frames(&self) -> &[F] {
        &self.frames
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.frames.len()
    }

    /// The demonstrated action sequence (no `<start>`/`<end>`).
    pub fn actions(&self) -> &[ActionId] {
        &self.actions
    }

    /// Number of actions (never zero).
    #[allow(clippy::len_without_is_empty)] // never empty by construction
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// The frame range of each segment (`actions.len() + 1` of them).
    pub fn segments(&self) -> impl ExactSizeIterator<Item = std::ops::Range<usize>> + '_ {
        self.segment_ends
            .iter()
            .enumerate()
            .map(|(s, &end)| if s == 0 { 0 } else { self.segment_ends[s - 1] }..end)
    }

    /// Frames per segment (segment 0 first).
    pub fn segment_lengths(&self) -> Vec<usize> {
        self.segments().map(|r| r.len()).collect()
    }

    /// The segment of each frame.
    pub fn frame_segments(&self) -> Vec<usize> {
        self.segments()
            .enumerate()
            .flat_map(|(s, r)| std::iter::repeat_n(s, r.len()))
            .collect()
    }

    /// The action each frame belongs to: `<start>` for segment 0, then the
    /// segment's action.
    pub fn frame_labels(&self) -> Vec<ActionId> {
        let nodes = self.node_labels();
        self.frame_segments()
            .into_iter()
            .map(|s| nodes[s])
            .collect()
    }

    /// The action that follows each frame's segment (`<end>` for the last).
    pub fn frame_next_actions(&self) -> Vec<ActionId> {
        let next = self.next_actions();
        self.frame_segments().into_iter().map(|s| next[s]).collect()
    }

    /// The CTG node of each segment: `<start>`, then each action.
    pub fn node_labels(&self) -> Vec<ActionId> {
        crate::demo::node_labels_of(&self.actions)
    }

    /// The action that follows each segment: each action, then `<end>`.
    pub fn next_actions(&self) -> Vec<ActionId> {
        crate::demo::next_actions_of(&self.actions)
    }

    /// Index of each segment's last frame (the scene once its action is done).
    pub fn keyframe_indices(&self) -> Vec<usize> {
        self.segment_ends.iter().map(|&e| e - 1).collect()
    }

    /// The keyframes as a [`Demonstration`]: one observation before the
    /// first action and one after each.
    pub fn keyframes(&self) -> Demonstration<F>
    where
        F: Clone,
    {
        Demonstration::from_validated(
            self.keyframe_indices()
                .into_iter()
                .map(|i| self.frames[i].clone())
                .collect(),
            self.actions.clone(),
        )
    }

    /// The same video with every frame transformed by `f` (for example
    /// encoded into a feature vector).
    pub fn map_frames<G>(self, f: impl FnMut(F) -> G) -> VideoDemonstration<G> {
        VideoDemonstration {
            frames: self.frames.into_iter().map(f).collect(),
            segment_ends: self.segment_ends,
            actions: self.actions,
        }
    }

    /// Splits into frames, segment ends and actions.
    pub fn into_parts(self) -> (Vec<F>, Vec<usize>, Vec<ActionId>) {
        (self.frames, self.segment_ends, self.actions)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab() -> Vocabulary {
        Vocabulary::new(["a", "b"]).unwrap()
    }

    #[test]
    fn labels_line_up_with_frames() {
        let v = vocab();
        let (a, b) = (v.id("a").unwrap(), v.id("b").unwrap());
        let video = VideoDemonstration::from_segments(
            vec![vec![0, 1], vec![2, 3, 4], vec![5]],
            vec![a, b],
            &v,
        )
        .unwrap();
        assert_eq!(video.segment_lengths(), [2, 3, 1]);
        assert_eq!(video.frame_segments(), [0, 0, 1, 1, 1, 2]);
        assert_eq!(
            video.frame_labels(),
            [Vocabulary::START, Vocabulary::START, a, a, a, b]
        );
        assert_eq!(video.frame_next_actions(), [a, a, b, b, b, Vocabulary::END]);
        assert_eq!(video.keyframe_indices(), [1, 4, 5]);
        let keys = video.keyframes();
        assert_eq!(keys.observations(), &[1, 4, 5]);
        assert_eq!(keys.node_labels(), video.node_labels());
        assert_eq!(video.clone().map_frames(|f| f * 10).frames()[2], 20);
    }

    #[test]
    fn repeated_actions_keep_their_own_segments() {
        let v = vocab();
        let a = v.id("a").unwrap();
        let video = VideoDemonstration::from_segments(
            vec![vec![0], vec![1, 2], vec![3, 4]],
            vec![a, a],
            &v,
        )
        .unwrap();
        assert_eq!(video.frame_segments(), [0, 1, 1, 2, 2]);
        assert_eq!(video.keyframes().len(), 2);
    }

    #[test]
    fn rejects_invalid_videos() {
        let v = vocab();
        let a = v.id("a").unwrap();
        assert_eq!(
            VideoDemonstration::<u8>::from_segments(vec![vec![0]], vec![], &v),
            Err(CtgError::EmptyDemonstration)
        );
        assert!(matches!(
            VideoDemonstration::from_segments(vec![vec![0], vec![]], vec![a], &v),
            Err(CtgError::VideoSegments { .. })
        ));
        assert!(matches!(
            VideoDemonstration::from_segments(vec![vec![0]], vec![a], &v),
            Err(CtgError::VideoSegments { expected: 2, .. })
        ));
        assert!(matches!(
            VideoDemonstration::new(vec![0, 1, 2], vec![1, 2], vec![a], &v),
            Err(CtgError::VideoSegments { .. })
        ));
        assert!(matches!(
            VideoDemonstration::from_segments(vec![vec![0], vec![1]], vec![Vocabulary::END], &v),
            Err(CtgError::ReservedAction("<end>"))
        ));
        let msg = VideoDemonstration::from_segments(vec![vec![0], vec![]], vec![a], &v)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("segment 1 is empty"), "{msg}");
    }
}
