//! The paper's figures as experiment configs: each figure is a TOML file in
//! `crates/ntg-trainer/experiments/` that lists, per profile, the runs it
//! trains (domain, method, observation, recipe, scale, seed, and any field
//! of the run configuration set by name) and how they are plotted. The
//! files are compiled in as the defaults; `ntg reproduce --experiments DIR`
//! reads edited copies from `DIR` instead.
//!
//! One module per figure turns its file into runs through the shared
//! training and evaluation code ([`crate::fit`], [`crate::domain`]) and
//! draws the result: [`ntp_exp`] (block stacking, success vs training
//! tasks) and [`thor_all`] (object collection, success vs objects); fig.
//! "jigsaws" reads `jigsaws.toml` through
//! [`crate::jigsaws::JigsawsConfig::for_profile`].

use std::path::Path;

use anyhow::{Context, bail};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::spec::Profile;

pub mod ntp_exp;
pub mod thor_all;

/// The experiment files compiled in: `(name, contents)`.
pub const BUILT_IN: [(&str, &str); 3] = [
    ("ntp_exp", include_str!("../../experiments/ntp_exp.toml")),
    ("thor_all", include_str!("../../experiments/thor_all.toml")),
    ("jigsaws", include_str!("../../experiments/jigsaws.toml")),
];

/// One table per profile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profiles<P> {
    /// `smoke`.
    pub smoke: P,
    /// `quick`.
    pub quick: P,
    /// `paper`.
    pub paper: P,
}

impl<P> Profiles<P> {
    /// The table of `profile`.
    pub fn get(&self, profile: Profile) -> &P {
        match profile {
            Profile::Smoke => &self.smoke,
            Profile::Quick => &self.quick,
            Profile::Paper => &self.paper,
        }
    }
}

/// A profile's table that only sets fields of the run configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileOverrides {
    /// Fields of the run configuration set at this profile.
    #[serde(default)]
    pub overrides: toml::Table,
}

/// Where experiment files are read from.
#[derive(Debug, Clone, Copy, Default)]
pub enum Source<'a> {
    /// The copies compiled into the binary.
    #[default]
    BuiltIn,
    /// `DIR/NAME.toml`.
    Dir(&'a Path),
}

/// Reads and parses experiment `name` (e.g. `ntp_exp`) from `source`, and
/// says where it came from (for messages); errors name the file and the
/// problem.
pub fn load<T: DeserializeOwned>(name: &str, source: Source<'_>) -> anyhow::Result<(T, String)> {
    let (text, origin) = match source {
        Source::BuiltIn => {
            let text = BUILT_IN
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, t)| (*t).to_owned())
                .with_context(|| format!("no built-in experiment named {name}"))?;
            (text, format!("experiments/{name}.toml (built in)"))
        }
        Source::Dir(dir) => {
            let path = dir.join(format!("{name}.toml"));
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            (text, path.display().to_string())
        }
    };
    let value = toml::from_str(&text).with_context(|| format!("{origin}: invalid experiment"))?;
    Ok((value, origin))
}

/// `base` with the fields named in `overrides` replaced (nested tables
/// replace nested fields). Every key must name a field `base` has, so a
/// misspelt key is an error, not a silently ignored setting.
pub fn with_overrides<C>(base: &C, overrides: &toml::Table, what: &str) -> anyhow::Result<C>
where
    C: Serialize + DeserializeOwned,
{
    let mut value = serde_json::to_value(base)?;
    let overrides = serde_json::to_value(overrides)?;
    merge(&mut value, &overrides, "")
        .with_context(|| format!("applying the overrides of {what}"))?;
    serde_json::from_value(value).with_context(|| format!("applying the overrides of {what}"))
}

fn merge(base: &mut Value, overrides: &Value, path: &str) -> anyhow::Result<()> {
    let (Value::Object(base), Value::Object(overrides)) = (base, overrides) else {
        bail!("{path} is not a table");
    };
    for (key, new) in overrides {
        let name = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        let Some(old) = base.get_mut(key) else {
            let known: Vec<&str> = base.keys().map(String::as_str).collect();
            bail!(
                "unknown setting `{name}` (known here: {})",
                known.join(", ")
            );
        };
        if old.is_object() && new.is_object() {
            merge(old, new, &name)?;
        } else {
            *old = new.clone();
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::OptimConfig;

    fn optim() -> OptimConfig {
        OptimConfig {
            epochs: 1,
            batch_size: 32,
            learning_rate: 1e-3,
            seed: 0,
            token_dropout: 0.0,
            gcn_from_other_demo: false,
            cosine_decay: false,
            shards: 1,
        }
    }

    #[test]
    fn overrides_replace_named_fields_and_refuse_unknown_ones() {
        let table: toml::Table =
            toml::from_str("learning_rate = 3e-3\ncosine_decay = true").unwrap();
        let c = with_overrides(&optim(), &table, "test").unwrap();
        assert_eq!(c.learning_rate, 3e-3);
        assert!(c.cosine_decay);
        assert_eq!(c.batch_size, 32);
        let typo: toml::Table = toml::from_str("learning_rte = 3e-3").unwrap();
        let err = format!(
            "{:#}",
            with_overrides(&optim(), &typo, "x.toml").unwrap_err()
        );
        assert!(
            err.contains("x.toml") && err.contains("unknown setting `learning_rte`"),
            "{err}"
        );
        let wrong_type: toml::Table = toml::from_str("epochs = \"many\"").unwrap();
        assert!(with_overrides(&optim(), &wrong_type, "x.toml").is_err());
    }

    #[test]
    fn every_built_in_experiment_parses() {
        let e = ntp_exp::NtpExpExperiment::load(Source::BuiltIn).unwrap();
        assert_eq!(e.origin, "experiments/ntp_exp.toml (built in)");
        thor_all::ThorAllExperiment::load(Source::BuiltIn).unwrap();
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("nope", Source::BuiltIn).unwrap_err()
        );
        assert!(err.contains("nope"), "{err}");
    }

    #[test]
    fn experiment_files_from_a_folder_name_the_file_in_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("ntp_exp.toml"), "domain = [").unwrap();
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("ntp_exp", Source::Dir(dir.path())).unwrap_err()
        );
        assert!(
            err.contains("ntp_exp.toml") && err.contains("invalid"),
            "{err}"
        );
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("thor_all", Source::Dir(dir.path())).unwrap_err()
        );
        assert!(err.contains("thor_all.toml"), "{err}");
    }

    #[test]
    fn a_misspelt_setting_in_an_edited_copy_is_an_error_naming_the_copy() {
        let dir = tempfile::tempdir().unwrap();
        let (_, built_in) = BUILT_IN.iter().find(|(n, _)| *n == "ntp_exp").unwrap();
        let edited = built_in.replace("pairwise = true", "pairwse = true");
        assert_ne!(&edited, built_in);
        std::fs::write(dir.path().join("ntp_exp.toml"), edited).unwrap();
        let experiment = ntp_exp::NtpExpExperiment::load(Source::Dir(dir.path())).unwrap();
        let err = format!("{:#}", experiment.run_configs(Profile::Quick).unwrap_err());
        assert!(
            err.contains("ntp_exp.toml") && err.contains("unknown setting `pairwse`"),
            "{err}"
        );
        assert!(!err.contains("built in"), "{err}");
    }
}
