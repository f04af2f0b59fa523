//! Transcriptions (`<start_frame> <end_frame> G<k>` per line) and meta files.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{Problem, Result};
use crate::kinematics::parse_error;
use crate::{Gesture, Skill, Task, TrialId};

/// One labelled gesture segment: frames `start_frame..=end_frame` (1-based,
/// inclusive; frame `f` is kinematics row `f - 1`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Segment {
    /// First frame (1-based).
    pub start_frame: u32,
    /// Last frame (1-based, inclusive, `>= start_frame`).
    pub end_frame: u32,
    /// The gesture performed.
    pub gesture: Gesture,
}

impl Segment {
    /// Kinematics row of the first frame.
    pub fn start_row(&self) -> usize {
        self.start_frame as usize - 1
    }

    /// Kinematics row of the last frame (inclusive).
    pub fn end_row(&self) -> usize {
        self.end_frame as usize - 1
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        (self.end_frame - self.start_frame) as usize + 1
    }
}

/// Parses a transcription file's text: one segment per non-blank line,
/// `<start_frame> <end_frame> G<k>` separated by any whitespace (trailing
/// spaces are common). Frames are positive, `end >= start`, and segments are
/// in order (each starts after the previous one starts). Frames between
/// segments are unlabelled. A segment that starts before the previous one
/// ends is accepted (see [`overlapping_segments`]; the loader reports it as
/// a warning). `path` is only used in error messages.
pub fn parse_transcription(text: &str, path: &Path) -> Result<Vec<Segment>> {
    let mut segments: Vec<Segment> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.is_empty() {
            continue;
        }
        let &[start, end, gesture] = fields.as_slice() else {
            return Err(parse_error(
                path,
                i,
                Problem::SegmentFields { got: fields.len() },
            ));
        };
        let frame = |token: &str| -> Result<u32> {
            match token.parse::<u32>() {
                Ok(0) => Err(parse_error(path, i, Problem::FrameZero)),
                Ok(f) => Ok(f),
                Err(_) => Err(parse_error(
                    path,
                    i,
                    Problem::BadFrame {
                        token: token.to_owned(),
                    },
                )),
            }
        };
        let (start, end) = (frame(start)?, frame(end)?);
        if end < start {
            return Err(parse_error(path, i, Problem::EndBeforeStart { start, end }));
        }
        let gesture = Gesture::parse(gesture).ok_or_else(|| {
            parse_error(
                path,
                i,
                Problem::UnknownGesture {
                    token: gesture.to_owned(),
                },
            )
        })?;
        if let Some(prev) = segments.last()
            && start <= prev.start_frame
        {
            return Err(parse_error(
                path,
                i,
                Problem::OutOfOrder {
                    start,
                    previous_start: prev.start_frame,
                },
            ));
        }
        segments.push(Segment {
            start_frame: start,
            end_frame: end,
            gesture,
        });
    }
    Ok(segments)
}

/// Indices of the segments that start at or before the end of the previous
/// segment (overlaps, which the real annotations are not expected to have).
pub fn overlapping_segments(segments: &[Segment]) -> Vec<usize> {
    (1..segments.len())
        .filter(|&i| segments[i].start_frame <= segments[i - 1].end_frame)
        .collect()
}

/// 1-based line numbers of the segments of a transcription text (its
/// non-blank lines), for messages about segment `i`.
pub fn segment_lines(text: &str) -> Vec<usize> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, _)| n + 1)
        .collect()
}

/// The text of a transcription file (one `start end Gk ` line per segment,
/// with the trailing space of the real files).
pub fn format_transcription(segments: &[Segment]) -> String {
    let mut out = String::new();
    for s in segments {
        let _ = writeln!(out, "{} {} {} ", s.start_frame, s.end_frame, s.gesture);
    }
    out
}

/// One row of a task's meta file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MetaRecord {
    /// The trial.
    pub trial: TrialId,
    /// Self-rated skill.
    pub skill: Skill,
    /// Global rating score total (6–30).
    pub grs_total: u8,
    /// The six modified-OSATS sub-scores (1–5 each): respect for tissue,
    /// suture/needle handling, time and motion, flow of operation, overall
    /// performance, quality of final product.
    pub grs: [u8; 6],
}

/// Names of the six GRS sub-scores, in file order.
pub const GRS_ITEMS: [&str; 6] = [
    "respect for tissue",
    "suture/needle handling",
    "time and motion",
    "flow of operation",
    "overall performance",
    "quality of final product",
];

/// Parses a meta file of `task`: tab-separated rows (empty fields from
/// doubled tabs are dropped; surrounding spaces are trimmed) of trial id,
/// skill letter, GRS total (6–30) and six sub-scores (1–5). Blank lines are
/// skipped; a trial listed twice or belonging to another task is an error.
/// Returns the rows with their 1-based line numbers.
pub fn parse_meta_file(text: &str, task: Task, path: &Path) -> Result<Vec<(usize, MetaRecord)>> {
    let mut rows: Vec<(usize, MetaRecord)> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line
            .split('\t')
            .map(str::trim)
            .filter(|f| !f.is_empty())
            .collect();
        if fields.is_empty() {
            continue;
        }
        if fields.len() != 9 {
            return Err(parse_error(
                path,
                i,
                Problem::MetaFields { got: fields.len() },
            ));
        }
        let trial = TrialId::parse(fields[0]).ok_or_else(|| {
            parse_error(
                path,
                i,
                Problem::BadTrialId {
                    token: fields[0].to_owned(),
                },
            )
        })?;
        if trial.task != task {
            return Err(parse_error(
                path,
                i,
                Problem::WrongTask {
                    trial,
                    expected: task,
                },
            ));
        }
        if let Some((first, _)) = rows.iter().find(|(_, r)| r.trial == trial) {
            return Err(parse_error(
                path,
                i,
                Problem::DuplicateTrial {
                    trial,
                    first_line: *first,
                },
            ));
        }
        let skill = Skill::parse(fields[1]).ok_or_else(|| {
            parse_error(
                path,
                i,
                Problem::BadSkill {
                    token: fields[1].to_owned(),
                },
            )
        })?;
        let score = |token: &str, field: &'static str, min: u8, max: u8| -> Result<u8> {
            token
                .parse::<u8>()
                .ok()
                .filter(|v| (min..=max).contains(v))
                .ok_or_else(|| {
                    parse_error(
                        path,
                        i,
                        Problem::BadScore {
                            field,
                            token: token.to_owned(),
                            min,
                            max,
                        },
                    )
                })
        };
        let grs_total = score(fields[2], "GRS total", 6, 30)?;
        let mut grs = [0u8; 6];
        for (k, g) in grs.iter_mut().enumerate() {
            *g = score(fields[3 + k], GRS_ITEMS[k], 1, 5)?;
        }
        rows.push((
            i + 1,
            MetaRecord {
                trial,
                skill,
                grs_total,
                grs,
            },
        ));
    }
    Ok(rows)
}

/// The text of a meta file: fields separated by doubled tabs, as in the real
/// files.
pub fn format_meta_file(records: &[MetaRecord]) -> String {
    let mut out = String::new();
    for r in records {
        let _ = write!(
            out,
            "{}\t\t{}\t\t{}",
            r.trial,
            r.skill.letter(),
            r.grs_total
        );
        for g in r.grs {
            let _ = write!(out, "\t\t{g}");
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> String {
        parse_transcription(text, Path::new("t.txt"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn parses_segments_with_trailing_spaces_and_gaps() {
        let s = parse_transcription("80 219 G1 \n220 300 G5\r\n\n305 400 G8 \n", Path::new("t"))
            .unwrap();
        assert_eq!(s.len(), 3);
        assert_eq!(s[0].start_row(), 79);
        assert_eq!(s[0].num_frames(), 140);
        assert_eq!(s[2].gesture, Gesture::G8);
        assert_eq!(
            parse_transcription(&format_transcription(&s), Path::new("t")).unwrap(),
            s
        );
    }

    #[test]
    fn each_malformed_line_is_a_named_error() {
        assert_eq!(
            err("1 5 G1\n9 7 G2\n"),
            "t.txt:2: segment ends at frame 7, before it starts at frame 9"
        );
        assert_eq!(
            err("1 5 G16\n"),
            "t.txt:1: unknown gesture `G16` (expected G1 to G15)"
        );
        assert_eq!(
            err("1 x G1\n"),
            "t.txt:1: `x` is not a frame number (a positive integer)"
        );
        assert_eq!(
            err("0 4 G1\n"),
            "t.txt:1: frame numbers are 1-based; 0 is not a frame"
        );
        assert_eq!(
            err("\n1 4\n"),
            "t.txt:2: a segment needs 3 fields `<start_frame> <end_frame> G<k>`, found 2"
        );
        assert_eq!(
            err("5 10 G1\n5 20 G2\n"),
            "t.txt:2: segment starting at frame 5 is out of order: the previous segment starts at frame 5"
        );
        // Overlaps parse, and are found.
        let s = parse_transcription("1 10 G1\n10 20 G2\n21 22 G3\n", Path::new("t")).unwrap();
        assert_eq!(overlapping_segments(&s), [1]);
        assert_eq!(segment_lines("\n1 2 G1\n  \n3 4 G2\n"), [2, 4]);
    }

    #[test]
    fn meta_rows_drop_empty_fields() {
        let text = "Knot_Tying_B001\t\tN\t\t13\t\t2\t\t2\t\t2\t\t3\t\t2\t\t2\n\nKnot_Tying_D002 \t\tE\t\t24\t\t4\t\t4\t\t4\t\t4\t\t4\t\t4\n";
        let rows = parse_meta_file(text, Task::KnotTying, Path::new("m")).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].0, 3);
        let r = rows[0].1;
        assert_eq!(r.trial.to_string(), "Knot_Tying_B001");
        assert_eq!(
            (r.skill, r.grs_total, r.grs),
            (Skill::Novice, 13, [2, 2, 2, 3, 2, 2])
        );
        let records: Vec<_> = rows.iter().map(|(_, r)| *r).collect();
        let back =
            parse_meta_file(&format_meta_file(&records), Task::KnotTying, Path::new("m")).unwrap();
        assert_eq!(
            back.into_iter().map(|(_, r)| r).collect::<Vec<_>>(),
            records
        );
    }

    #[test]
    fn meta_errors() {
        let e = |t: &str| {
            parse_meta_file(t, Task::Suturing, Path::new("m"))
                .unwrap_err()
                .to_string()
        };
        assert_eq!(
            e("Suturing_B001\tN\t13\n"),
            "m:1: a meta row needs 9 non-empty fields (trial id, skill, GRS total, six sub-scores), found 3"
        );
        assert_eq!(
            e("Suturing_B001\tX\t13\t2\t2\t2\t3\t2\t2\n"),
            "m:1: `X` is not a skill level (N, I or E)"
        );
        assert_eq!(
            e("Suturing_B001\tN\t31\t2\t2\t2\t3\t2\t2\n"),
            "m:1: GRS total: `31` is not an integer from 6 to 30"
        );
        assert_eq!(
            e("Suturing_B001\tN\t13\t2\t2\t2\t6\t2\t2\n"),
            "m:1: flow of operation: `6` is not an integer from 1 to 5"
        );
        assert_eq!(
            e("Suturing_B1\tN\t13\t2\t2\t2\t3\t2\t2\n"),
            "m:1: `Suturing_B1` is not a trial id `<Task>_<Surgeon><NNN>`"
        );
        assert_eq!(
            e("Knot_Tying_B001\tN\t13\t2\t2\t2\t3\t2\t2\n"),
            "m:1: trial `Knot_Tying_B001` belongs to another task than Suturing"
        );
        let row = "Suturing_B001\tN\t13\t2\t2\t2\t3\t2\t2\n";
        assert_eq!(
            e(&format!("{row}{row}")),
            "m:2: trial `Suturing_B001` is listed twice (first on line 1)"
        );
    }
}
