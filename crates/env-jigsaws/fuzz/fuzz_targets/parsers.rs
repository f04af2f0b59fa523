//! Fuzzes the transcription, kinematics and meta-file parsers: none may
//! panic, and whatever parses must survive a write → parse round trip.
#![no_main]

use std::path::Path;

use env_jigsaws::{
    Kinematics, MetaRecord, Task, format_meta_file, format_transcription, parse_meta_file,
    parse_transcription,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let path = Path::new("fuzz.txt");

    if let Ok(segments) = parse_transcription(&text, path) {
        let again = parse_transcription(&format_transcription(&segments), path)
            .expect("formatted transcription parses");
        assert_eq!(again, segments);
        for pair in segments.windows(2) {
            assert!(pair[0].start_frame < pair[1].start_frame);
        }
        for s in &segments {
            assert!(s.start_frame >= 1 && s.end_frame >= s.start_frame);
        }
    }

    if let Ok(kinematics) = Kinematics::parse(&text, path) {
        assert!(kinematics.as_flat().iter().all(|v| v.is_finite()));
        let again =
            Kinematics::parse(&kinematics.to_text(), path).expect("formatted kinematics parse");
        assert_eq!(again, kinematics);
    }

    for task in Task::ALL {
        if let Ok(rows) = parse_meta_file(&text, task, path) {
            let records: Vec<MetaRecord> = rows.into_iter().map(|(_, r)| r).collect();
            let again: Vec<MetaRecord> = parse_meta_file(&format_meta_file(&records), task, path)
                .expect("formatted meta file parses")
                .into_iter()
                .map(|(_, r)| r)
                .collect();
            assert_eq!(again, records);
        }
    }
});
