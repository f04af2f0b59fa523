//! Kinematics: 76 floats per row at 30 Hz, four arm groups of 19.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{JigsawsError, Problem, Result};

/// Values per kinematics row.
pub const KINEMATICS_COLUMNS: usize = 76;
/// Values per arm group.
pub const ARM_COLUMNS: usize = 19;
/// Kinematics (and video) frame rate, frames per second.
pub const FRAME_RATE: f64 = 30.0;

/// One of the four arms recorded in a kinematics row, in column order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Arm {
    /// Master tool manipulator, left (columns 1–19).
    MasterLeft,
    /// Master tool manipulator, right (columns 20–38).
    MasterRight,
    /// Patient-side manipulator, left (columns 39–57).
    PatientLeft,
    /// Patient-side manipulator, right (columns 58–76).
    PatientRight,
}

impl Arm {
    /// The four arms in column order.
    pub const ALL: [Arm; 4] = [
        Arm::MasterLeft,
        Arm::MasterRight,
        Arm::PatientLeft,
        Arm::PatientRight,
    ];

    /// 0-based index of this arm's first column.
    pub fn offset(self) -> usize {
        ARM_COLUMNS
            * match self {
                Arm::MasterLeft => 0,
                Arm::MasterRight => 1,
                Arm::PatientLeft => 2,
                Arm::PatientRight => 3,
            }
    }
}

/// Column offsets inside one arm group of 19.
pub mod group {
    /// Tool-tip position x, y, z (metres): columns 0..3 of the group.
    pub const POSITION: std::ops::Range<usize> = 0..3;
    /// Tool-tip rotation matrix, row-major: columns 3..12.
    pub const ROTATION: std::ops::Range<usize> = 3..12;
    /// Tool-tip linear velocity (metres per second): columns 12..15.
    pub const LINEAR_VELOCITY: std::ops::Range<usize> = 12..15;
    /// Tool-tip angular velocity (radians per second): columns 15..18.
    pub const ANGULAR_VELOCITY: std::ops::Range<usize> = 15..18;
    /// Gripper angle (radians): column 18.
    pub const GRIPPER_ANGLE: usize = 18;
}

/// One arm's 19 values of one row, typed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ArmState {
    /// Tool-tip position (x, y, z).
    pub position: [f32; 3],
    /// Tool-tip rotation matrix, `rotation[r][c]` (stored row-major).
    pub rotation: [[f32; 3]; 3],
    /// Linear velocity.
    pub linear_velocity: [f32; 3],
    /// Angular velocity.
    pub angular_velocity: [f32; 3],
    /// Gripper angle.
    pub gripper_angle: f32,
}

impl ArmState {
    /// Reads the 19 values of one group (`values.len()` must be at least 19;
    /// returns `None` otherwise).
    pub fn from_slice(values: &[f32]) -> Option<ArmState> {
        let v = values.get(..ARM_COLUMNS)?;
        let three = |r: std::ops::Range<usize>| [v[r.start], v[r.start + 1], v[r.start + 2]];
        let rot = &v[group::ROTATION];
        Some(ArmState {
            position: three(group::POSITION),
            rotation: [
                [rot[0], rot[1], rot[2]],
                [rot[3], rot[4], rot[5]],
                [rot[6], rot[7], rot[8]],
            ],
            linear_velocity: three(group::LINEAR_VELOCITY),
            angular_velocity: three(group::ANGULAR_VELOCITY),
            gripper_angle: v[group::GRIPPER_ANGLE],
        })
    }

    /// Writes the 19 values into `out[..19]` (no-op if `out` is shorter).
    pub fn write_to(&self, out: &mut [f32]) {
        let Some(out) = out.get_mut(..ARM_COLUMNS) else {
            return;
        };
        out[group::POSITION].copy_from_slice(&self.position);
        for (r, row) in self.rotation.iter().enumerate() {
            out[3 + 3 * r..6 + 3 * r].copy_from_slice(row);
        }
        out[group::LINEAR_VELOCITY].copy_from_slice(&self.linear_velocity);
        out[group::ANGULAR_VELOCITY].copy_from_slice(&self.angular_velocity);
        out[group::GRIPPER_ANGLE] = self.gripper_angle;
    }
}

/// A trial's kinematics: `num_rows()` rows of [`KINEMATICS_COLUMNS`] values,
/// stored row-major. Row `r` is video frame `r + 1`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Kinematics {
    data: Vec<f32>,
}

impl Kinematics {
    /// Kinematics from row-major values. Errors (`None`) unless the length is
    /// a multiple of 76.
    pub fn from_flat(data: Vec<f32>) -> Option<Kinematics> {
        data.len()
            .is_multiple_of(KINEMATICS_COLUMNS)
            .then_some(Kinematics { data })
    }

    /// Number of rows (frames).
    pub fn num_rows(&self) -> usize {
        self.data.len() / KINEMATICS_COLUMNS
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// All values, row-major.
    pub fn as_flat(&self) -> &[f32] {
        &self.data
    }

    /// Row `r` (76 values), if it exists.
    pub fn row(&self, r: usize) -> Option<&[f32]> {
        self.data
            .get(r * KINEMATICS_COLUMNS..(r + 1) * KINEMATICS_COLUMNS)
    }

    /// Iterates over the rows.
    pub fn rows(&self) -> impl Iterator<Item = &[f32]> {
        self.data.chunks_exact(KINEMATICS_COLUMNS)
    }

    /// One arm's typed state at row `r`.
    pub fn arm(&self, r: usize, arm: Arm) -> Option<ArmState> {
        ArmState::from_slice(&self.row(r)?[arm.offset()..])
    }

    /// Parses a kinematics file's text: one row per non-blank line, 76
    /// whitespace-separated (runs of spaces or tabs) finite numbers. `path`
    /// is only used in error messages. Errors name the line (1-based) and,
    /// for a bad number, the column.
    pub fn parse(text: &str, path: &Path) -> Result<Kinematics> {
        let mut data = Vec::with_capacity(text.len() / 10);
        for (i, line) in text.lines().enumerate() {
            let mut count = 0;
            for token in line.split_ascii_whitespace() {
                count += 1;
                if count > KINEMATICS_COLUMNS {
                    let got = line.split_ascii_whitespace().count();
                    return Err(parse_error(
                        path,
                        i,
                        Problem::LongRow {
                            expected: KINEMATICS_COLUMNS,
                            got,
                        },
                    ));
                }
                let value: f32 = token.parse().map_err(|_| {
                    parse_error(
                        path,
                        i,
                        Problem::NotANumber {
                            column: count,
                            token: token.to_owned(),
                        },
                    )
                })?;
                if !value.is_finite() {
                    return Err(parse_error(
                        path,
                        i,
                        Problem::NotFinite {
                            column: count,
                            token: token.to_owned(),
                        },
                    ));
                }
                data.push(value);
            }
            if count != 0 && count < KINEMATICS_COLUMNS {
                return Err(parse_error(
                    path,
                    i,
                    Problem::ShortRow {
                        expected: KINEMATICS_COLUMNS,
                        got: count,
                    },
                ));
            }
        }
        Ok(Kinematics { data })
    }

    /// The file text: one line per row, values right-aligned in runs of
    /// spaces as in the real files, each printed so that it parses back to
    /// the same `f32`.
    pub fn to_text(&self) -> String {
        let mut out = String::with_capacity(self.data.len() * 12);
        for row in self.rows() {
            for v in row {
                // Display of f32 is the shortest text that parses back exactly.
                let _ = write!(out, " {v:>12}");
            }
            out.push('\n');
        }
        out
    }
}

pub(crate) fn parse_error(path: &Path, line_index: usize, problem: Problem) -> JigsawsError {
    JigsawsError::Parse {
        path: path.to_owned(),
        line: line_index + 1,
        problem,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row_text(values: &[f32]) -> String {
        values
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join("   ")
    }

    #[test]
    fn parses_rows_with_runs_of_spaces_and_blank_lines() {
        let row: Vec<f32> = (0..76).map(|i| i as f32 * 0.5 - 3.0).collect();
        let text = format!(
            "  {}\n\n\t{}  \r\n",
            row_text(&row),
            row_text(&row).replace("   ", " \t ")
        );
        let k = Kinematics::parse(&text, Path::new("k.txt")).unwrap();
        assert_eq!(k.num_rows(), 2);
        assert_eq!(k.row(1).unwrap(), row.as_slice());
        let arm = k.arm(0, Arm::PatientRight).unwrap();
        assert_eq!(arm.position, [row[57], row[58], row[59]]);
        assert_eq!(arm.rotation[1], [row[63], row[64], row[65]]);
        assert_eq!(arm.gripper_angle, row[75]);
        let mut back = vec![0.0; 19];
        arm.write_to(&mut back);
        assert_eq!(back, row[57..76]);
    }

    #[test]
    fn text_round_trips_exactly() {
        let data: Vec<f32> = (0..76 * 3)
            .map(|i| (i as f32 * 0.37).sin() * 10f32.powi(i % 7 - 4))
            .collect();
        let k = Kinematics::from_flat(data).unwrap();
        assert_eq!(Kinematics::parse(&k.to_text(), Path::new("x")).unwrap(), k);
    }

    #[test]
    fn errors_name_line_and_column() {
        let good = row_text(&[1.0; 76]);
        let short = row_text(&[1.0; 75]);
        let err = Kinematics::parse(&format!("{good}\n{short}\n"), Path::new("a/k.txt"))
            .unwrap_err()
            .to_string();
        assert_eq!(err, "a/k.txt:2: short row: expected 76 values, found 75");

        let long = row_text(&[1.0; 77]);
        let err = Kinematics::parse(&long, Path::new("k"))
            .unwrap_err()
            .to_string();
        assert_eq!(err, "k:1: long row: expected 76 values, found 77");

        let mut tokens = vec!["1"; 76];
        tokens[11] = "1.2.3";
        let err = Kinematics::parse(&format!("\n{}", tokens.join(" ")), Path::new("k"))
            .unwrap_err()
            .to_string();
        assert_eq!(err, "k:2: column 12: `1.2.3` is not a number");

        let nan = good.replacen("1", "NaN", 1);
        let err = Kinematics::parse(&nan, Path::new("k"))
            .unwrap_err()
            .to_string();
        assert_eq!(err, "k:1: column 1: `NaN` is not a finite number");
    }

    #[test]
    fn from_flat_checks_length() {
        assert!(Kinematics::from_flat(vec![0.0; 75]).is_none());
        assert_eq!(Kinematics::from_flat(vec![0.0; 152]).unwrap().num_rows(), 2);
    }
}
