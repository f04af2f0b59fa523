//! Property tests: formats round-trip, parsers never panic, observations
//! always line up with segments.

use std::path::Path;

use env_jigsaws::{
    ColumnStats, Gesture, Kinematics, MetaRecord, ObservationConfig, ObservationEncoder, Segment,
    Skill, Task, Trial, TrialId, format_transcription, parse_meta_file, parse_transcription,
};
use proptest::prelude::*;

/// Ordered, non-overlapping segments (gaps allowed) and the frame count.
fn segments() -> impl Strategy<Value = (Vec<Segment>, usize)> {
    prop::collection::vec((0u32..4, 1u32..30, 1u8..=15), 1..12).prop_map(|parts| {
        let mut frame = 0;
        let segs: Vec<Segment> = parts
            .into_iter()
            .map(|(gap, len, g)| {
                let start = frame + gap + 1;
                frame = start + len - 1;
                Segment {
                    start_frame: start,
                    end_frame: frame,
                    gesture: Gesture::new(g).unwrap(),
                }
            })
            .collect();
        (segs, frame as usize)
    })
}

proptest! {
    #[test]
    fn transcription_round_trips((segs, _) in segments()) {
        let text = format_transcription(&segs);
        prop_assert_eq!(parse_transcription(&text, Path::new("t")).unwrap(), segs);
    }

    #[test]
    fn kinematics_round_trip(values in prop::collection::vec(
        prop::num::f32::NORMAL | prop::num::f32::ZERO | prop::num::f32::SUBNORMAL, 76..=228)) {
        let rows = values.len() / 76;
        let k = Kinematics::from_flat(values[..rows * 76].to_vec()).unwrap();
        prop_assert_eq!(Kinematics::parse(&k.to_text(), Path::new("k")).unwrap(), k);
    }

    #[test]
    fn parsers_never_panic(text in "[ 0-9GENI\t\n.e_a-zA-Z-]{0,300}") {
        let _ = parse_transcription(&text, Path::new("t"));
        let _ = Kinematics::parse(&text, Path::new("k"));
        let _ = parse_meta_file(&text, Task::Suturing, Path::new("m"));
    }

    #[test]
    fn transcription_results_are_valid(text in "([0-9]{1,3} [0-9]{1,3} G[0-9]{1,2} ?\n){0,6}") {
        if let Ok(segs) = parse_transcription(&text, Path::new("t")) {
            for w in segs.windows(2) {
                prop_assert!(w[0].start_frame < w[1].start_frame);
            }
            for s in &segs {
                prop_assert!(s.start_frame >= 1 && s.end_frame >= s.start_frame);
            }
        }
    }

    #[test]
    fn demonstrations_line_up_with_segments(
        (segs, frames) in segments(),
        extra in 0usize..5,
        window in 1usize..6,
        stride in 1usize..8,
    ) {
        let rows = frames + extra;
        let kin = Kinematics::from_flat((0..rows * 76).map(|i| (i % 977) as f32).collect()).unwrap();
        let meta = MetaRecord {
            trial: TrialId::new(Task::Suturing, 'B', 1),
            skill: Skill::Novice,
            grs_total: 12,
            grs: [2; 6],
        };
        let trial = Trial::new(meta, segs.clone(), kin).unwrap();
        let enc = ObservationEncoder::new(ObservationConfig { window, stride }, ColumnStats::identity()).unwrap();
        let demo = enc.demonstration(&trial).unwrap();
        prop_assert_eq!(demo.len(), segs.len());
        prop_assert_eq!(demo.observations().len(), segs.len() + 1);
        for o in demo.observations() {
            prop_assert_eq!(o.len(), window * 76);
        }
        for (a, s) in demo.actions().iter().zip(&segs) {
            prop_assert_eq!(Gesture::from_action_id(*a), Some(s.gesture));
        }
        // The newest row of observation i is the row before segment i starts.
        for (i, s) in segs.iter().enumerate() {
            let newest = &demo.observations()[i][(window - 1) * 76..];
            let row = trial.kinematics.row(s.start_row().saturating_sub(1)).unwrap();
            prop_assert_eq!(newest, row);
        }
    }
}
