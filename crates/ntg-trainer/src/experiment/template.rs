//! The report's prose: Markdown templates in
//! `crates/ntg-trainer/experiments/report/`, one file per part of
//! `REPORT.md`, compiled in (so the binary writes its report from any
//! folder) and filled from the results by the report code.
//!
//! A template file is a series of named parts, each opened by a line
//! `<!-- part: NAME -->` and running to the next such line; what comes
//! before the first part (a comment for whoever edits the prose) is not
//! used. A part's text is its lines without the blank lines at either end:
//! the code that fills it adds the blank lines between blocks. A line that
//! starts with spaces continues the line before it (the line break and the
//! spaces read as one space, as in a Markdown paragraph), so that a long
//! paragraph can be wrapped. In a part, `{name}` is a value filled in by the
//! code (numbers already formatted), and `{{` and `}}` stand for `{` and `}`.
//!
//! A placeholder without a value, a value that the part does not use and a
//! part that is not in its file are errors. The templates are compiled in,
//! so such an error is a bug: [`Template::fill`] panics on it, and a test
//! fills every part of every file from results that reach every branch of
//! the report (`reproduce::tests::every_part_of_every_template_is_filled`).

use std::fmt::{Display, Write as _};

/// One template file.
#[derive(Debug, Clone, Copy)]
pub struct Template {
    /// Its name in `experiments/report/` (for messages).
    pub file: &'static str,
    /// Its text.
    pub text: &'static str,
}

macro_rules! templates {
    ($($name:ident: $file:literal),* $(,)?) => {
        $(
            #[doc = concat!("`experiments/report/", $file, "`.")]
            pub const $name: Template = Template {
                file: $file,
                text: include_str!(concat!("../../experiments/report/", $file)),
            };
        )*
        /// Every template file.
        pub const ALL: &[Template] = &[$($name),*];
    };
}

templates! {
    REPORT: "report.md",
    NTP_EXP: "ntp_exp.md",
    ABLATION: "ablation.md",
    QUALITATIVE: "qualitative.md",
    STRUCTURE: "structure.md",
    JIGSAWS: "jigsaws.md",
    THOR_ALL: "thor_all.md",
    ZOO: "zoo.md",
}

/// The line that opens a part: `<!-- part: NAME -->`.
const OPEN: (&str, &str) = ("<!-- part: ", " -->");

#[cfg(test)]
thread_local! {
    /// The parts filled on this thread, `(file, part)`.
    pub static FILLED: std::cell::RefCell<std::collections::BTreeSet<(&'static str, String)>> =
        Default::default();
}

impl Template {
    /// The file's parts, `(name, text)` in order, continuation lines joined.
    pub fn parts(&self) -> Vec<(&'static str, String)> {
        let mut parts: Vec<(&'static str, String)> = Vec::new();
        for line in self.text.lines() {
            let opened = line
                .strip_prefix(OPEN.0)
                .and_then(|l| l.strip_suffix(OPEN.1));
            match (opened, parts.last_mut()) {
                (Some(name), _) => parts.push((name, String::new())),
                (None, None) => {}
                (None, Some((_, text))) if line.starts_with(' ') && !text.ends_with('\n') => {
                    text.push(' ');
                    text.push_str(line.trim_start());
                }
                (None, Some((_, text))) => {
                    if !text.is_empty() {
                        text.push('\n');
                    }
                    text.push_str(line);
                }
            }
        }
        for (_, text) in &mut parts {
            *text = text.trim_matches('\n').to_owned();
        }
        parts
    }

    /// Part `part` with each placeholder filled from `values` (`(name,
    /// value)`). Panics where the part is not in the file, a placeholder
    /// has no value or a value is not used (see the module docs).
    pub fn fill(&self, part: &str, values: &[(&str, &dyn Display)]) -> String {
        self.try_fill(part, values)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    /// Part `part`, which has no placeholder.
    pub fn text(&self, part: &str) -> String {
        self.fill(part, &[])
    }

    /// [`Template::fill`], with its errors as messages.
    pub fn try_fill(&self, part: &str, values: &[(&str, &dyn Display)]) -> Result<String, String> {
        #[cfg(test)]
        FILLED.with(|f| f.borrow_mut().insert((self.file, part.to_owned())));
        let error = |what: String| format!("experiments/report/{}, part {part}: {what}", self.file);
        let parts = self.parts();
        let (_, text) = parts
            .iter()
            .find(|(name, _)| *name == part)
            .ok_or_else(|| error("no such part".into()))?;
        let mut used = vec![false; values.len()];
        let (mut out, mut rest) = (String::new(), text.as_str());
        while let Some(at) = rest.find(['{', '}']) {
            out.push_str(&rest[..at]);
            let (brace, after) = (&rest[at..=at], &rest[at + 1..]);
            if let Some(after) = after.strip_prefix(brace) {
                out.push_str(brace);
                rest = after;
                continue;
            }
            let end = after.find('}').filter(|_| brace == "{");
            let end =
                end.ok_or_else(|| error(format!("a lone `{brace}` (write `{brace}{brace}`)")))?;
            let name = &after[..end];
            let value = values.iter().position(|(n, _)| *n == name);
            let value = value.ok_or_else(|| error(format!("no value for {{{name}}}")))?;
            used[value] = true;
            let _ = write!(out, "{}", values[value].1);
            rest = &after[end + 1..];
        }
        out.push_str(rest);
        match used.iter().position(|&u| !u) {
            Some(unused) => Err(error(format!("{} is given but not used", values[unused].0))),
            None => Ok(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Template = Template {
        file: "t.md",
        text: "<!-- Not used. -->\n<!-- part: a -->\n\nRate {rate}, {{braces}}\n  and more.\n\n| x |\n|---|\n\n\
               <!-- part: b -->\nno value {missing}\n<!-- part: c -->\n{{ and } alone\n",
    };

    #[test]
    fn a_part_is_filled_with_its_values_and_continuation_lines_joined() {
        assert_eq!(
            T.fill("a", &[("rate", &format!("{:.3}", 0.5))]),
            "Rate 0.500, {braces} and more.\n\n| x |\n|---|"
        );
        assert_eq!(
            T.parts().iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            ["a", "b", "c"]
        );
    }

    #[test]
    fn a_missing_or_unused_value_or_part_is_an_error() {
        let err = T.try_fill("b", &[]).unwrap_err();
        assert_eq!(
            err,
            "experiments/report/t.md, part b: no value for {missing}"
        );
        let err = T.try_fill("a", &[("rate", &1), ("other", &2)]).unwrap_err();
        assert!(err.ends_with("other is given but not used"), "{err}");
        assert!(
            T.try_fill("nope", &[])
                .unwrap_err()
                .ends_with("no such part")
        );
        assert!(
            T.try_fill("c", &[])
                .unwrap_err()
                .ends_with("a lone `}` (write `}}`)")
        );
    }

    #[test]
    fn every_file_has_parts_of_distinct_names() {
        for template in ALL {
            let parts = template.parts();
            assert!(!parts.is_empty(), "{}", template.file);
            for (i, (name, text)) in parts.iter().enumerate() {
                assert!(!text.is_empty(), "{}: part {name} is empty", template.file);
                assert!(
                    parts[..i].iter().all(|(other, _)| other != name),
                    "{}: two parts {name}",
                    template.file
                );
            }
        }
    }
}
