//! Contact sheets: many frames tiled into one image, and a video
//! demonstration's sheet with one labelled row per flat action.

use ctg_graph::{VideoDemonstration, Vocabulary};
use image::{Rgb, RgbImage};

const BACKGROUND: Rgb<u8> = Rgb([30, 30, 30]);
const LABEL: Rgb<u8> = Rgb([235, 235, 235]);
const KEYFRAME: Rgb<u8> = Rgb([250, 200, 40]);

/// Tiles `frames` (all the same size) into a grid `columns` wide, each frame
/// scaled up by the integer `scale`, with a `gap`-pixel dark border.
/// An empty list gives a 1×1 image.
pub fn contact_sheet(frames: &[&RgbImage], columns: usize, scale: u32, gap: u32) -> RgbImage {
    let Some(first) = frames.first() else {
        return RgbImage::new(1, 1);
    };
    let columns = columns.clamp(1, frames.len()) as u32;
    let rows = (frames.len() as u32).div_ceil(columns);
    let scale = scale.max(1);
    let (fw, fh) = (first.width() * scale, first.height() * scale);
    let width = columns * fw + (columns + 1) * gap;
    let height = rows * fh + (rows + 1) * gap;
    let mut sheet = RgbImage::from_pixel(width, height, BACKGROUND);
    for (k, frame) in frames.iter().enumerate() {
        let (c, r) = (k as u32 % columns, k as u32 / columns);
        let (x0, y0) = (gap + c * (fw + gap), gap + r * (fh + gap));
        for y in 0..fh.min(frame.height() * scale) {
            for x in 0..fw.min(frame.width() * scale) {
                let p = *frame.get_pixel(x / scale, y / scale);
                sheet.put_pixel(x0 + x, y0 + y, p);
            }
        }
    }
    sheet
}

/// [`contact_sheet`] with a caption under each frame (`frames[k].1`,
/// upper-cased, in the sheet's 3×5 font at scale 1; clipped to the cell):
/// which step a frame shows and what was done there.
pub fn captioned_contact_sheet(
    frames: &[(&RgbImage, String)],
    columns: usize,
    scale: u32,
    gap: u32,
) -> RgbImage {
    let Some((first, _)) = frames.first() else {
        return RgbImage::new(1, 1);
    };
    let columns = columns.clamp(1, frames.len()) as u32;
    let rows = (frames.len() as u32).div_ceil(columns);
    let scale = scale.max(1);
    let (fw, fh) = (first.width() * scale, first.height() * scale);
    // The caption's 5 font rows, with 2 pixels above and below.
    let caption = 9;
    let width = columns * fw + (columns + 1) * gap;
    let height = rows * (fh + caption) + (rows + 1) * gap;
    let mut sheet = RgbImage::from_pixel(width, height, BACKGROUND);
    for (k, (frame, text)) in frames.iter().enumerate() {
        let (c, r) = (k as u32 % columns, k as u32 / columns);
        let (x0, y0) = (gap + c * (fw + gap), gap + r * (fh + caption + gap));
        for y in 0..fh.min(frame.height() * scale) {
            for x in 0..fw.min(frame.width() * scale) {
                sheet.put_pixel(x0 + x, y0 + y, *frame.get_pixel(x / scale, y / scale));
            }
        }
        // At most the characters that fit the cell's width.
        let fit: String = text.chars().take((fw / 4).max(1) as usize).collect();
        draw_label(&mut sheet, x0, y0 + fh + 2, &fit, 1, LABEL);
    }
    sheet
}

/// A 3×5 pixel glyph (rows top to bottom, 3 bits each, high bit left) for
/// the characters of action names (upper-cased); `None` for others.
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        'A' => [0b010, 0b101, 0b111, 0b101, 0b101],
        'B' => [0b110, 0b101, 0b110, 0b101, 0b110],
        'C' => [0b011, 0b100, 0b100, 0b100, 0b011],
        'D' => [0b110, 0b101, 0b101, 0b101, 0b110],
        'E' => [0b111, 0b100, 0b110, 0b100, 0b111],
        'F' => [0b111, 0b100, 0b110, 0b100, 0b100],
        'G' => [0b011, 0b100, 0b101, 0b101, 0b011],
        'H' => [0b101, 0b101, 0b111, 0b101, 0b101],
        'I' => [0b111, 0b010, 0b010, 0b010, 0b111],
        'K' => [0b101, 0b101, 0b110, 0b101, 0b101],
        'L' => [0b100, 0b100, 0b100, 0b100, 0b111],
        'M' => [0b101, 0b111, 0b111, 0b101, 0b101],
        'N' => [0b110, 0b101, 0b101, 0b101, 0b101],
        'O' => [0b010, 0b101, 0b101, 0b101, 0b010],
        'P' => [0b110, 0b101, 0b110, 0b100, 0b100],
        'R' => [0b110, 0b101, 0b110, 0b101, 0b101],
        'S' => [0b011, 0b100, 0b010, 0b001, 0b110],
        'T' => [0b111, 0b010, 0b010, 0b010, 0b010],
        'V' => [0b101, 0b101, 0b101, 0b101, 0b010],
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b110, 0b001, 0b010, 0b100, 0b111],
        '3' => [0b110, 0b001, 0b010, 0b001, 0b110],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b110, 0b001, 0b110],
        '6' => [0b011, 0b100, 0b110, 0b101, 0b010],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b010, 0b101, 0b010, 0b101, 0b010],
        '9' => [0b010, 0b101, 0b011, 0b001, 0b110],
        'J' => [0b001, 0b001, 0b001, 0b101, 0b010],
        'Q' => [0b010, 0b101, 0b101, 0b110, 0b011],
        'U' => [0b101, 0b101, 0b101, 0b101, 0b111],
        'W' => [0b101, 0b101, 0b111, 0b111, 0b101],
        'X' => [0b101, 0b101, 0b010, 0b101, 0b101],
        'Y' => [0b101, 0b101, 0b010, 0b010, 0b010],
        'Z' => [0b111, 0b001, 0b010, 0b100, 0b111],
        '_' => [0, 0, 0, 0, 0b111],
        '-' => [0, 0, 0b111, 0, 0],
        '.' => [0, 0, 0, 0, 0b010],
        ':' => [0, 0b010, 0, 0b010, 0],
        '(' => [0b010, 0b100, 0b100, 0b100, 0b010],
        ')' => [0b010, 0b001, 0b001, 0b001, 0b010],
        '<' => [0b001, 0b010, 0b100, 0b010, 0b001],
        '>' => [0b100, 0b010, 0b001, 0b010, 0b100],
        ' ' => [0; 5],
        _ => return None,
    })
}

/// Writes `text` (upper-cased; unknown characters as a hollow box) with its
/// top-left corner at `(x, y)`, each font pixel `scale` pixels wide; clipped
/// to the image. Characters advance 4 font pixels.
pub fn draw_label(image: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, colour: Rgb<u8>) {
    let scale = scale.max(1);
    for (k, c) in text.chars().flat_map(char::to_uppercase).enumerate() {
        let rows = glyph(c).unwrap_or([0b111, 0b101, 0b101, 0b101, 0b111]);
        let x0 = x + k as u32 * 4 * scale;
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..3u32 {
                if bits & (0b100 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (x0 + col * scale + dx, y + r as u32 * scale + dy);
                        if px < image.width() && py < image.height() {
                            image.put_pixel(px, py, colour);
                        }
                    }
                }
            }
        }
    }
}

/// A video demonstration's contact sheet: one row per segment (`<start>`,
/// then each flat action), labelled on the left with the segment's action
/// name (from `vocab`), its frames scaled up by `scale`, the keyframe (the
/// segment's last frame) framed in yellow.
pub fn video_contact_sheet(
    video: &VideoDemonstration<RgbImage>,
    vocab: &Vocabulary,
    scale: u32,
) -> RgbImage {
    let scale = scale.max(1);
    let gap = 2 * scale;
    let Some(first) = video.frames().first() else {
        return RgbImage::new(1, 1);
    };
    let (fw, fh) = (first.width() * scale, first.height() * scale);
    let labels: Vec<&str> = video
        .node_labels()
        .into_iter()
        .map(|a| vocab.name(a).unwrap_or("?"))
        .collect();
    let chars = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    let label_width = chars * 4 * scale + 2 * gap;
    let columns = video.segment_lengths().into_iter().max().unwrap_or(1) as u32;
    let width = label_width + columns * (fw + gap) + gap;
    let rows = labels.len() as u32;
    let height = rows * (fh + gap) + gap;
    let mut sheet = RgbImage::from_pixel(width, height, BACKGROUND);
    for (s, (range, label)) in video.segments().zip(&labels).enumerate() {
        let y0 = gap + s as u32 * (fh + gap);
        draw_label(
            &mut sheet,
            gap,
            y0 + (fh.saturating_sub(5 * scale)) / 2,
            label,
            scale,
            LABEL,
        );
        let last = range.end - 1;
        for (c, k) in range.enumerate() {
            let x0 = label_width + c as u32 * (fw + gap);
            let frame = &video.frames()[k];
            if k == last {
                // A one-pixel-per-scale frame around the keyframe, in the gap.
                let b = scale.min(gap);
                for y in y0 - b..y0 + fh + b {
                    for x in x0 - b..x0 + fw + b {
                        if x < width && y < height {
                            sheet.put_pixel(x, y, KEYFRAME);
                        }
                    }
                }
            }
            for y in 0..fh.min(frame.height() * scale) {
                for x in 0..fw.min(frame.width() * scale) {
                    sheet.put_pixel(x0 + x, y0 + y, *frame.get_pixel(x / scale, y / scale));
                }
            }
        }
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_frames_in_a_grid() {
        let a = RgbImage::from_pixel(4, 4, Rgb([255, 0, 0]));
        let b = RgbImage::from_pixel(4, 4, Rgb([0, 255, 0]));
        let sheet = contact_sheet(&[&a, &b, &a], 2, 2, 1);
        assert_eq!(sheet.dimensions(), (2 * 8 + 3, 2 * 8 + 3));
        assert_eq!(sheet.get_pixel(1, 1), &Rgb([255, 0, 0]));
        assert_eq!(sheet.get_pixel(10, 1), &Rgb([0, 255, 0]));
        assert_eq!(sheet.get_pixel(1, 10), &Rgb([255, 0, 0]));
        assert_eq!(sheet.get_pixel(0, 0), &Rgb([30, 30, 30]));
        assert_eq!(contact_sheet(&[], 3, 1, 0).dimensions(), (1, 1));
    }

    #[test]
    fn captions_go_under_their_frames() {
        let a = RgbImage::from_pixel(8, 8, Rgb([255, 0, 0]));
        let sheet = captioned_contact_sheet(
            &[(&a, "0 <start>".into()), (&a, "1 pick(A)".into())],
            2,
            2,
            1,
        );
        assert_eq!(sheet.dimensions(), (2 * 16 + 3, 16 + 9 + 2));
        // The caption's first glyph ('0': a full top row) under frame 0.
        let y = 1 + 16 + 2;
        assert_eq!(sheet.get_pixel(1, y), &LABEL);
        assert_eq!(sheet.get_pixel(1, 1), &Rgb([255, 0, 0]));
        // Every character of the captions has a glyph.
        for c in
            "0123456789 <START> <END> PICK(A) PLACE(BIN2) MOVE GRASP DROP: SLIPPED MISSED".chars()
        {
            assert!(glyph(c).is_some(), "{c:?}");
        }
    }

    #[test]
    fn video_sheet_has_one_labelled_row_per_segment() {
        let vocab = Vocabulary::new(["pick(A)", "place(bin2)"]).unwrap();
        let a = RgbImage::from_pixel(4, 4, Rgb([255, 0, 0]));
        let b = RgbImage::from_pixel(4, 4, Rgb([0, 0, 255]));
        let video = VideoDemonstration::from_segments(
            vec![
                vec![a.clone()],
                vec![a.clone(), b.clone(), b.clone()],
                vec![b],
            ],
            vocab.parse_sequence("pick(A) place(bin2)").unwrap(),
            &vocab,
        )
        .unwrap();
        let sheet = video_contact_sheet(&video, &vocab, 2);
        let (fw, gap) = (8, 4);
        let label_width = 11 * 4 * 2 + 2 * gap;
        assert_eq!(sheet.width(), label_width + 3 * (fw + gap) + gap);
        assert_eq!(sheet.height(), 3 * (fw + gap) + gap);
        // Row 1, second frame: blue; its keyframe (third) is framed.
        let y = gap + (fw + gap) + 1;
        assert_eq!(
            sheet.get_pixel(label_width + fw + gap + 1, y),
            &Rgb([0, 0, 255])
        );
        assert_eq!(
            sheet.get_pixel(label_width + 2 * (fw + gap) - 1, y),
            &KEYFRAME
        );
        // Something is written in the label column of every row.
        for row in 0..3 {
            let y0 = gap + row * (fw + gap);
            let lit = (y0..y0 + fw)
                .flat_map(|y| (0..label_width).map(move |x| (x, y)))
                .any(|(x, y)| sheet.get_pixel(x, y) == &LABEL);
            assert!(lit, "row {row} has no label");
        }
    }
}
