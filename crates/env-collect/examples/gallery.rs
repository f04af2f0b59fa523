//! Writes the category gallery (every category on every surface, with
//! varied sizes and tints) and every receptacle with contents, to check the
//! renderer by eye: `cargo run -p env-collect --example gallery -- OUT_DIR`.

use std::path::PathBuf;

use env_collect::render::{self, Appearance, Backdrop};
use env_collect::{Category, Receptacle};
use image::RgbImage;
use rand::SeedableRng;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&out)?;
    render::category_gallery(1).save(out.join("gallery.png"))?;

    let mut frames = Vec::new();
    for (k, r) in Receptacle::ALL.into_iter().enumerate() {
        for count in [0usize, 3, 5] {
            let mut img = RgbImage::new(render::FRAME_SIZE, render::FRAME_SIZE);
            let backdrop = Backdrop {
                tint: [1.0; 3],
                phase: 0,
                salt: k as u64,
            };
            render::draw_receptacle(&mut img, r, &backdrop);
            for i in 0..count {
                let look = Appearance {
                    size: render::RECEPTACLE_OBJECT_SIZE,
                    tint: [1.0; 3],
                    variant: i as u8,
                };
                let (x, y) = render::receptacle_slot(r, i);
                let c = Category::ALL[(i + k) % Category::ALL.len()];
                render::draw_object(&mut img, c, x, y, look.size, &look);
            }
            let held = Appearance {
                size: render::HAND_OBJECT_SIZE,
                tint: [1.0; 3],
                variant: 0,
            };
            render::draw_hand(&mut img, (count == 3).then_some((Category::Mug, &held)));
            render::add_noise(&mut img, k as u64);
            frames.push((
                img,
                if count == 0 {
                    r.name().to_owned()
                } else {
                    String::new()
                },
            ));
        }
    }
    let cells: Vec<(&RgbImage, String)> = frames.iter().map(|(f, s)| (f, s.clone())).collect();
    render::contact_sheet(&cells, 3, 2).save(out.join("receptacles.png"))?;
    for n in [1, 3, 5] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(n as u64);
        let task = env_collect::TaskSplitter::default().sample(n, None, &mut rng)?;
        let dir = out.join(format!("demo_n{n}"));
        let written = env_collect::export::write_demo(&dir, &task, n as u64, &Default::default())?;
        println!("{task}: {} actions", written.demo.len());
    }
    println!("wrote {}", out.display());
    Ok(())
}
