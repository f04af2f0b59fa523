//! Contact sheets: many frames tiled into one image.

use image::{Rgb, RgbImage};

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
    let mut sheet = RgbImage::from_pixel(width, height, Rgb([30, 30, 30]));
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
}
