//! The seed-sensitivity table: the experiment repeated with one seed changed at a time.

use super::*;

/// One setting of the [`seed_table`]: the base configuration with at most
/// one seed changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SeedSetting {
    /// The base configuration.
    Default,
    /// Another seed of the synthetic data.
    Data(u64),
    /// Another seed of both models' initial weights.
    Model(u64),
}

impl SeedSetting {
    /// The settings of the table: the default, synthetic-data seeds 1–3
    /// (synthetic data only) and model seeds 1–5.
    pub fn all(source: &DataSource) -> Vec<SeedSetting> {
        let data: &[u64] = match source {
            DataSource::Synthetic { .. } => &[1, 2, 3],
            DataSource::Root { .. } => &[],
        };
        std::iter::once(SeedSetting::Default)
            .chain(data.iter().map(|&s| SeedSetting::Data(s)))
            .chain((1..=5).map(SeedSetting::Model))
            .collect()
    }

    /// Name in reports and run folders: `default`, `data1`, `model2`.
    pub fn name(self) -> String {
        match self {
            SeedSetting::Default => "default".to_owned(),
            SeedSetting::Data(s) => format!("data{s}"),
            SeedSetting::Model(s) => format!("model{s}"),
        }
    }

    /// `base` with this setting's seed. Errors for a data seed on a
    /// dataset read from disk.
    pub fn apply(self, base: &JigsawsConfig) -> anyhow::Result<JigsawsConfig> {
        let mut config = base.clone();
        match (self, &mut config.source) {
            (SeedSetting::Default, _) => {}
            (SeedSetting::Model(s), _) => config.model_seed = s,
            (SeedSetting::Data(s), DataSource::Synthetic { seed, .. }) => *seed = s,
            (SeedSetting::Data(_), DataSource::Root { path }) => bail!(
                "{}: a dataset on disk has no data seed to change",
                path.display()
            ),
        }
        Ok(config)
    }
}

/// One row of the [`seed_table`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedRow {
    /// The setting.
    pub setting: SeedSetting,
    /// Mean NLL over conditioning demos, per method in [`Method::ALL`]
    /// order.
    pub nll: Vec<(Method, f64)>,
    /// [`Method::Full`]'s selected prior weight.
    pub prior_weight: Option<f64>,
}

impl SeedRow {
    /// The mean NLL of `method`.
    pub fn nll(&self, method: Method) -> Option<f64> {
        self.nll.iter().find(|(m, _)| *m == method).map(|&(_, v)| v)
    }

    fn of(setting: SeedSetting, result: &JigsawsResult) -> SeedRow {
        SeedRow {
            setting,
            nll: result
                .methods
                .iter()
                .map(|m| (m.method, m.mean_nll))
                .collect(),
            prior_weight: result
                .runs
                .iter()
                .find(|r| r.method == Method::Full)
                .and_then(|r| r.selection.prior_weight),
        }
    }
}

/// The experiment repeated with one seed changed at a time
/// ([`SeedSetting::all`]): does full NTG beat no graph whatever the seeds?
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedTable {
    /// One row per setting.
    pub rows: Vec<SeedRow>,
}

impl SeedTable {
    /// Settings where `a` scored a lower NLL than `b`.
    pub fn wins(&self, a: Method, b: Method) -> usize {
        self.rows
            .iter()
            .filter(|r| matches!((r.nll(a), r.nll(b)), (Some(x), Some(y)) if x < y))
            .count()
    }

    /// Mean over settings of `method`'s NLL.
    pub fn mean(&self, method: Method) -> f64 {
        let v: Vec<f64> = self.rows.iter().filter_map(|r| r.nll(method)).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }
}

/// Runs the experiment of `base` once per [`SeedSetting::all`] (run folders
/// under `<runs>/jigsaws-seeds/<setting>/`, reused when finished), taking
/// the default row from `done` when given (the result of `base` itself).
pub fn seed_table(
    base: &JigsawsConfig,
    done: Option<&JigsawsResult>,
    runs: &Path,
    mut log: impl FnMut(&str),
) -> anyhow::Result<SeedTable> {
    let mut rows = Vec::new();
    for setting in SeedSetting::all(&base.source) {
        let row = match (setting, done) {
            (SeedSetting::Default, Some(result)) => SeedRow::of(setting, result),
            _ => {
                let config = setting.apply(base)?;
                log(&format!("jigsaws seed table: {}", setting.name()));
                let dir = runs.join("jigsaws-seeds").join(setting.name());
                let result = run_experiment(&config, &dir, |line| {
                    if !line.starts_with("  epoch") {
                        log(line);
                    }
                })?;
                SeedRow::of(setting, &result)
            }
        };
        rows.push(row);
    }
    Ok(SeedTable { rows })
}

/// The seed table as Markdown (a table and a one-line summary).
pub fn seed_table_markdown(table: &SeedTable) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| setting | no graph | NTG, own head | NTG (full) | τ | full < no graph |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    let cell = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.3}"));
    for r in &table.rows {
        let (ng, full) = (r.nll(Method::NoGraph), r.nll(Method::Full));
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            r.setting.name(),
            cell(ng),
            cell(r.nll(Method::FullOwnHead)),
            cell(full),
            r.prior_weight.map_or("–".to_owned(), |w| w.to_string()),
            match (full, ng) {
                (Some(f), Some(n)) if f < n => "yes",
                _ => "**no**",
            }
        );
    }
    let n = table.rows.len();
    let _ = writeln!(
        s,
        "| mean | {:.3} | {:.3} | {:.3} | | full lower in {} of {n}; own head lower than no graph in {} of {n} |",
        table.mean(Method::NoGraph),
        table.mean(Method::FullOwnHead),
        table.mean(Method::Full),
        table.wins(Method::Full, Method::NoGraph),
        table.wins(Method::FullOwnHead, Method::NoGraph),
    );
    s
}
