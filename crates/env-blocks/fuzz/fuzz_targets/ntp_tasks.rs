//! Fuzzes the NTP task-file parser (`ntg blocks tasks --source FILE`,
//! `ntg blocks demo --source FILE`): it may refuse any input but never
//! panic, and whatever parses must survive a write -> parse round trip.
//!
//! `cargo +nightly fuzz run ntp_tasks seeds/ -- -max_total_time=600`
#![no_main]

use env_blocks::{parse_ntp_tasks, write_ntp_tasks};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(tasks) = parse_ntp_tasks(&text, "fuzz.json") {
        let again = parse_ntp_tasks(&write_ntp_tasks(&tasks), "written.json")
            .expect("a written task file parses");
        assert_eq!(again, tasks);
    }
});
