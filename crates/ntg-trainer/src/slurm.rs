//! A profile as Slurm job arrays: the submit script `ntg cluster slurm`
//! writes ([`submit_script`]).
//!
//! The runs are `ntg reproduce --list`'s ([`crate::reproduce::run_list`]).
//! One array per wave and kind of run (state or video, which need
//! different memory and time), each task `ntg reproduce --array-index`
//! with its index in that list read from `SLURM_ARRAY_TASK_ID`. A wave's
//! arrays wait (`--dependency=afterany`) for the earlier waves' arrays,
//! whose finished frame encoders its runs reuse; a last job writes the
//! figures and the report. Tasks are requeued on preemption and, a little
//! before their time limit, requeue themselves; a requeued task resumes its
//! run from its checkpoints.

use std::fmt::Write as _;

use crate::reproduce::ListedRun;

/// What the script is written for; everything else is a variable the user
/// edits in its header.
#[derive(Debug, Clone)]
pub struct ScriptSettings {
    /// The profile's name (`ntg reproduce --profile`).
    pub profile: String,
    /// The `ntg` binary the tasks run.
    pub ntg: String,
    /// The shared runs folder (`--runs`).
    pub runs: String,
    /// Where figures, results and records go (`--out`).
    pub out: String,
    /// Experiment files read instead of the built-in ones
    /// (`--experiments`).
    pub experiments: Option<String>,
}

/// One array of the script: a wave's runs of one kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Array {
    /// The wave.
    pub wave: usize,
    /// `"state"` or `"video"`.
    pub kind: &'static str,
    /// The list indices it runs, ascending.
    pub indices: Vec<usize>,
}

impl Array {
    /// The indices in `sbatch --array` notation (`0-5,9,12-14`).
    pub fn spec(&self) -> String {
        compress(&self.indices)
    }
}

/// The arrays of `list`: by wave, state before video.
pub fn arrays(list: &[ListedRun]) -> Vec<Array> {
    let mut arrays: Vec<Array> = Vec::new();
    let mut keys: Vec<(usize, &'static str)> = list.iter().map(|r| (r.wave, r.kind)).collect();
    keys.sort_by_key(|&(wave, kind)| (wave, kind != "state"));
    keys.dedup();
    for (wave, kind) in keys {
        arrays.push(Array {
            wave,
            kind,
            indices: list
                .iter()
                .filter(|r| r.wave == wave && r.kind == kind)
                .map(|r| r.index)
                .collect(),
        });
    }
    arrays
}

/// `0,1,2,5,7,8` → `0-2,5,7-8`.
fn compress(indices: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < indices.len() {
        let start = indices[i];
        let mut end = start;
        while i + 1 < indices.len() && indices[i + 1] == end + 1 {
            i += 1;
            end = indices[i];
        }
        parts.push(if end == start {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
        i += 1;
    }
    parts.join(",")
}

/// `value` escaped for the inside of a double-quoted shell word (`$`,
/// `` ` ``, `"` and `\` escaped), so that a default in the script's header
/// is taken literally.
fn literal(value: &str) -> String {
    let mut out = String::new();
    for c in value.chars() {
        if matches!(c, '$' | '`' | '"' | '\\') {
            out.push('\\');
        }
        out.push(c);
    }
    out
}

/// The submit script for `list` (a profile's runs): run it with `bash`, it
/// calls `sbatch` once per array and once for the report.
pub fn submit_script(list: &[ListedRun], settings: &ScriptSettings) -> String {
    let arrays = arrays(list);
    let profile = &settings.profile;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "#!/usr/bin/env bash\n\
         # ntg-rs, profile `{profile}`, as Slurm job arrays. Written by `ntg cluster slurm`;\n\
         # submit with `bash THIS_FILE` (it calls sbatch once per array, then once for the report).\n\
         #\n\
         # {n} runs: `ntg reproduce --profile {profile} --list` (same binary, same experiment\n\
         # files), one array task each; a task trains, or resumes, or reuses, its run with\n\
         # `ntg reproduce --array-index`, which reads the index from SLURM_ARRAY_TASK_ID.",
        n = list.len()
    );
    let _ = writeln!(s, "# Arrays (wave, kind: list indices):");
    for a in &arrays {
        let _ = writeln!(
            s,
            "#   wave {}, {}: {} ({} run{})",
            a.wave,
            a.kind,
            a.spec(),
            a.indices.len(),
            if a.indices.len() == 1 { "" } else { "s" }
        );
    }
    s.push_str(
        "# A wave's arrays start once every array of the waves before it has ended\n\
         # (--dependency=afterany): its runs link the finished frame encoders and encoded\n\
         # episodes of earlier runs (`--list` names them) instead of training them again;\n\
         # a run that finds none trains its own, to the same result. The last job runs\n\
         # `ntg reproduce` once more: it reuses every finished run, trains whatever a task\n\
         # left unfinished, runs fig. jigsaws and writes the figures, results.json and\n\
         # REPORT.md into OUT.\n\
         #\n\
         # Preemption and time limits: tasks are submitted with --requeue, so a preempted\n\
         # task is queued again; a task that nears its time limit (Slurm signals it\n\
         # REQUEUE_BEFORE seconds ahead) requeues itself. Either way the run resumes from\n\
         # its last checkpoint and ends with the record an uninterrupted run has: ntg exits\n\
         # at once on SIGTERM, and checkpoints are only ever replaced whole.\n\
         #\n\
         # RUNS and OUT must be on a file system every node sees. A task locks its run\n\
         # folder (flock on RUN/train.lock): the file system must honour locks across\n\
         # nodes (NFSv4; NFSv3 with lockd; Lustre mounted with -o flock; GPFS). Two\n\
         # tasks never write the same file.\n\
         #\n\
         # Edit these (or set them in the environment before `bash THIS_FILE`):\n",
    );
    // `value` is written as it is: callers escape literal values.
    let setting = |s: &mut String, name: &str, value: &str, what: &str| {
        let comment = if what.is_empty() {
            String::new()
        } else {
            format!("  # {what}")
        };
        let _ = writeln!(s, ": \"${{{name}:={value}}}\"{comment}");
    };
    setting(
        &mut s,
        "NTG",
        &literal(&settings.ntg),
        "the ntg binary (a release build; --features cuda for GPUs)",
    );
    setting(
        &mut s,
        "RUNS",
        &literal(&settings.runs),
        "run folders (shared file system)",
    );
    setting(
        &mut s,
        "OUT",
        &literal(&settings.out),
        "figures, results.json, REPORT.md, records",
    );
    setting(
        &mut s,
        "EXPERIMENTS",
        &literal(settings.experiments.as_deref().unwrap_or("")),
        "experiment files instead of the built-in ones (empty: built in)",
    );
    setting(
        &mut s,
        "LOGS",
        "$OUT/slurm-logs",
        "one log per task: NAME_JOB_TASK.log",
    );
    setting(
        &mut s,
        "PARTITION",
        "",
        "--partition (empty: the cluster's default)",
    );
    setting(&mut s, "ACCOUNT", "", "--account (empty: none)");
    setting(
        &mut s,
        "DEVICE",
        "cpu",
        "ntg --device: cpu, or cuda / wgpu with a GPU build",
    );
    setting(
        &mut s,
        "STATE_CPUS",
        "1",
        "a state-input run trains on one thread",
    );
    setting(&mut s, "STATE_MEM", "8G", "");
    setting(&mut s, "STATE_TIME", "24:00:00", "");
    setting(
        &mut s,
        "VIDEO_CPUS",
        "2",
        "video runs encode frames on 2 threads",
    );
    setting(
        &mut s,
        "VIDEO_MEM",
        "24G",
        "128x128 frames: stage A reads a memory-mapped store of up to ~20 GB",
    );
    setting(&mut s, "VIDEO_TIME", "72:00:00", "");
    setting(
        &mut s,
        "VIDEO_GRES",
        "",
        "e.g. gpu:1 with DEVICE=cuda (empty: none)",
    );
    setting(&mut s, "REPORT_CPUS", "2", "");
    setting(&mut s, "REPORT_MEM", "24G", "");
    setting(&mut s, "REPORT_TIME", "24:00:00", "");
    setting(
        &mut s,
        "REQUEUE_BEFORE",
        "300",
        "seconds before the time limit at which a task requeues itself",
    );
    s.push_str(
        "# More sbatch options for every job, e.g. EXTRA_SBATCH=(--qos=long):\n\
         EXTRA_SBATCH=()\n\
         \n\
         set -euo pipefail\n\
         mkdir -p \"$LOGS\"\n\
         # The settings as the job scripts read them back (shell-quoted).\n\
         q() { printf '%q' \"$1\"; }\n\
         ntg_q=$(q \"$NTG\") runs_q=$(q \"$RUNS\") out_q=$(q \"$OUT\") device_q=$(q \"$DEVICE\")\n\
         experiments_q=\"\"\n\
         [ -n \"$EXPERIMENTS\" ] && experiments_q=\"--experiments $(q \"$EXPERIMENTS\")\"\n\
         common=(--requeue --open-mode=append \"${EXTRA_SBATCH[@]}\")\n\
         [ -n \"$PARTITION\" ] && common+=(--partition=\"$PARTITION\")\n\
         [ -n \"$ACCOUNT\" ] && common+=(--account=\"$ACCOUNT\")\n\
         \n",
    );
    let _ = writeln!(
        s,
        "# One array: submit_array NAME ARRAY AFTER CPUS MEM TIME GRES; prints its job id.\n\
         submit_array() {{\n\
         \x20   local dependency=() gres=()\n\
         \x20   [ -n \"$3\" ] && dependency=(--dependency=\"afterany:$3\")\n\
         \x20   [ -n \"$7\" ] && gres=(--gres=\"$7\")\n\
         \x20   sbatch --parsable --job-name=\"$1\" --array=\"$2\" \"${{dependency[@]}}\" \\\n\
         \x20       --cpus-per-task=\"$4\" --mem=\"$5\" --time=\"$6\" \"${{gres[@]}}\" \\\n\
         \x20       --signal=\"B:USR1@$REQUEUE_BEFORE\" --output=\"$LOGS/%x_%A_%a.log\" \"${{common[@]}}\" <<EOF\n\
         #!/usr/bin/env bash\n\
         # Near the time limit (USR1): requeue this task and stop ntg; the requeued task resumes.\n\
         $ntg_q reproduce --profile {profile} --runs $runs_q --out $out_q $experiments_q \\\n\
         \x20   --device $device_q --jobs 1 --array-index &\n\
         pid=\\$!\n\
         trap 'scontrol requeue \"\\${{SLURM_ARRAY_JOB_ID}}_\\${{SLURM_ARRAY_TASK_ID}}\"; kill -TERM \\$pid' USR1\n\
         status=0\n\
         while kill -0 \\$pid 2>/dev/null; do wait \\$pid && status=0 || status=\\$?; done\n\
         exit \\$status\n\
         EOF\n\
         }}\n"
    );
    s.push_str("\nids=()\n");
    for (k, a) in arrays.iter().enumerate() {
        let kind = a.kind.to_uppercase();
        // Every array of the earlier waves.
        let after: Vec<String> = arrays
            .iter()
            .enumerate()
            .filter(|(_, b)| b.wave < a.wave)
            .map(|(j, _)| format!("${{ids[{j}]}}"))
            .collect();
        let _ = writeln!(
            s,
            "ids[{k}]=$(submit_array \"ntg-{profile}-w{w}-{kind_l}\" \"{spec}\" \"{after}\" \
             \"${kind}_CPUS\" \"${kind}_MEM\" \"${kind}_TIME\" \"{gres}\")\n\
             echo \"wave {w}, {kind_l}: job ${{ids[{k}]}} (array {spec})\"",
            w = a.wave,
            kind_l = a.kind,
            spec = a.spec(),
            after = after.join(":"),
            gres = if a.kind == "video" { "$VIDEO_GRES" } else { "" },
        );
    }
    let all: Vec<String> = (0..arrays.len())
        .map(|j| format!("${{ids[{j}]}}"))
        .collect();
    let _ = writeln!(
        s,
        "\n# The report, once every array has ended.\n\
         report=$(sbatch --parsable --job-name=\"ntg-{profile}-report\" {dependency}\\\n\
         \x20   --cpus-per-task=\"$REPORT_CPUS\" --mem=\"$REPORT_MEM\" --time=\"$REPORT_TIME\" \\\n\
         \x20   --output=\"$LOGS/%x_%j.log\" \"${{common[@]}}\" <<EOF\n\
         #!/usr/bin/env bash\n\
         exec $ntg_q reproduce --profile {profile} --runs $runs_q --out $out_q $experiments_q \\\n\
         \x20   --device $device_q --jobs \"$REPORT_CPUS\"\n\
         EOF\n\
         )\n\
         echo \"report: job $report (writes $OUT/REPORT.md)\"",
        dependency = if all.is_empty() {
            String::new()
        } else {
            format!("--dependency=\"afterany:{}\" ", all.join(":"))
        },
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(index: usize, wave: usize, kind: &'static str) -> ListedRun {
        ListedRun {
            index,
            figure: "ntp_exp".into(),
            name: format!("r{index}"),
            wave,
            after: Vec::new(),
            kind,
        }
    }

    #[test]
    fn indices_compress_into_ranges() {
        assert_eq!(compress(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
        assert_eq!(compress(&[3]), "3");
        assert_eq!(compress(&[]), "");
    }

    #[test]
    fn arrays_split_waves_and_kinds_and_later_waves_wait() {
        let list = vec![
            run(0, 0, "state"),
            run(1, 0, "video"),
            run(2, 0, "state"),
            run(3, 1, "video"),
            run(4, 2, "video"),
        ];
        let a = arrays(&list);
        let specs: Vec<(usize, &str, String)> =
            a.iter().map(|a| (a.wave, a.kind, a.spec())).collect();
        assert_eq!(
            specs,
            vec![
                (0, "state", "0,2".to_owned()),
                (0, "video", "1".to_owned()),
                (1, "video", "3".to_owned()),
                (2, "video", "4".to_owned()),
            ]
        );
        let script = submit_script(
            &list,
            &ScriptSettings {
                profile: "smoke".into(),
                ntg: "/opt/ntg $HOME".into(),
                runs: "runs".into(),
                out: "out".into(),
                experiments: None,
            },
        );
        assert!(
            script.contains(
                r#"ids[2]=$(submit_array "ntg-smoke-w1-video" "3" "${ids[0]}:${ids[1]}""#
            ),
            "{script}"
        );
        assert!(
            script.contains(
                r#"ids[3]=$(submit_array "ntg-smoke-w2-video" "4" "${ids[0]}:${ids[1]}:${ids[2]}""#
            ),
            "{script}"
        );
        assert!(
            script.contains(r#"--dependency="afterany:${ids[0]}:${ids[1]}:${ids[2]}:${ids[3]}""#),
            "{script}"
        );
        // A default is taken literally, not expanded.
        assert!(
            script.contains(r#": "${NTG:=/opt/ntg \$HOME}""#),
            "{script}"
        );
    }
}
