//! Writes the contact sheet of a demonstration video (one labelled row per
//! flat action, keyframes framed in yellow).
//!
//! `cargo run -p env-blocks --example video_sheet -- [stack|sort] TASK SEED OUT.png [SCALE]`
//! (defaults: `stack 0 0 video_sheet.png 2`; TASK indexes the standard
//! stacking tasks or the standard sorting tasks; SCALE magnifies each frame).

use env_blocks::sheet::video_contact_sheet;
use env_blocks::{
    ActionLevel, BlocksTask, EnvConfig, VideoConfig, record_video_demo, standard_sort_tasks,
    standard_tasks, vocabulary,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |k: usize, default: &str| args.get(k).cloned().unwrap_or_else(|| default.into());
    let sorting = arg(0, "stack") == "sort";
    let index: usize = arg(1, "0").parse()?;
    let seed: u64 = arg(2, "0").parse()?;
    let out = arg(3, "video_sheet.png");
    let scale: u32 = arg(4, "2").parse()?;
    let task = if sorting {
        BlocksTask::Sort(standard_sort_tasks()?.swap_remove(index))
    } else {
        BlocksTask::Stack(standard_tasks()?.swap_remove(index))
    };
    let video = record_video_demo(task, EnvConfig::default(), seed, &VideoConfig::default())?;
    let vocab = vocabulary(sorting, ActionLevel::Flat);
    video_contact_sheet(&video, &vocab, scale).save(&out)?;
    println!(
        "{out}: {} frames, {} flat actions, segment lengths {:?}",
        video.num_frames(),
        video.len(),
        video.segment_lengths()
    );
    Ok(())
}
