//! Convolution without unfolding: the input in a *phase layout*, where
//! every kernel tap reads a plain strided matrix, and one small matrix
//! product per tap (`conv.rs` uses it where the input has many channels).
//!
//! With stride `s`, pad the image by `p` and split it into `s²` phase
//! planes by (row mod `s`, column mod `s`): phase `(a, b)` holds padded
//! pixel `(s·r + a, s·q + b)` at `(r, q)`, in rows of `Wq = ⌈(W+2p)/s⌉`.
//! Output pixel `(i, j)` reads, through tap `(ki, kj)`, padded pixel
//! `(s·i + ki, s·j + kj)`: phase `(ki mod s, kj mod s)` at `(i + ki/s, j +
//! kj/s)`. Counting the outputs in rows of `Wq` too ("wide" columns
//! `i·Wq + j`, the last `Wq − W_out` of each row unused), that is position
//! `i·Wq + j + (ki/s)·Wq + kj/s` of the phase plane: the same offset for
//! every output. So tap `(ki, kj)` reads the `[C, H_out·Wq]` matrix at that
//! offset of its phase, rows one plane apart, and
//!
//! - forward: `Y = Σ_taps W_tap · X_tap` (`W_tap = W[:, :, ki, kj]`);
//! - weight gradient: `∂W_tap = G · X_tapᵀ` (`G` widened with zeros);
//! - input gradient: `∂X_tap += W_tapᵀ · G`, accumulated into the phase
//!   layout's gradient, then gathered back onto the image.
//!
//! No `[C·k·k, L]` unfolding is written or read: the matrix kernels pack
//! the taps' views themselves. The wide rows cost `Wq/W_out − 1` more
//! columns (1/16 at the encoder's sizes).

use crate::conv::ConvGeometry;
use crate::matmul::{Matrix, gemm_into, gemm_into_rows};

/// The phase layout of one image of a convolution: `s²` phases × `C`
/// channels × `plane` values.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Phases {
    g: ConvGeometry,
    /// Values per row of a phase plane (and per wide output row), `Wq`.
    row: usize,
    /// Values per phase plane (rows × `Wq`, plus what the last tap's view
    /// reads past the end).
    plane: usize,
}

impl Phases {
    /// The layout of `g`'s images.
    pub(crate) fn new(g: ConvGeometry) -> Self {
        let (s, p, k) = (g.stride, g.padding, g.kernel);
        let rows = (g.height + 2 * p).div_ceil(s);
        let row = (g.width + 2 * p).div_ceil(s);
        let shift = (k - 1) / s;
        let last_read = (g.out_height() * row - 1) + shift * row + shift;
        Phases {
            g,
            row,
            plane: (rows * row).max(last_read + 1),
        }
    }

    /// Values of one image in this layout.
    pub(crate) fn image_len(&self) -> usize {
        self.g.stride * self.g.stride * self.g.channels * self.plane
    }

    /// Wide output columns `H_out · Wq`.
    fn wide(&self) -> usize {
        self.g.out_height() * self.row
    }

    /// Where tap `(ki, kj)`'s view of channel 0 starts.
    fn tap(&self, ki: usize, kj: usize) -> usize {
        let s = self.g.stride;
        ((ki % s) * s + kj % s) * self.g.channels * self.plane + (ki / s) * self.row + kj / s
    }

    /// The input columns `j` of phase column `b` (those with `(j + p) mod s
    /// = b`): the first one, and where the first lands in its phase row.
    fn phase_columns(&self, b: usize) -> Option<(usize, usize)> {
        let (s, p) = (self.g.stride, self.g.padding);
        // The smallest j ≥ 0 with j + p ≡ b (mod s).
        let j0 = (b + s - p % s) % s;
        (j0 < self.g.width).then_some((j0, (j0 + p) / s))
    }

    /// Where phase row `i` (input row `i`, channel `c`) of phase column
    /// `b` starts.
    fn row_start(&self, c: usize, i: usize, b: usize) -> usize {
        let s = self.g.stride;
        let i = i + self.g.padding;
        ((i % s) * s + b) * self.g.channels * self.plane + c * self.plane + (i / s) * self.row
    }

    /// Writes image `x` (`[C, H, W]`) into `out` (`image_len` values),
    /// which must be zero: only the image's values are written, so the
    /// padding keeps the zeros of the caller's freshly allocated buffer
    /// (zeroing it again here cost one more pass over the whole layout).
    pub(crate) fn split(&self, x: &[f32], out: &mut [f32]) {
        let (g, s) = (self.g, self.g.stride);
        debug_assert!(
            out.iter().all(|&v| v == 0.0),
            "split into a non-zero buffer"
        );
        for (c, plane) in x.chunks(g.height * g.width).enumerate() {
            for (i, row) in plane.chunks(g.width).enumerate() {
                for b in 0..s {
                    let Some((j0, q0)) = self.phase_columns(b) else {
                        continue;
                    };
                    let dst = &mut out[self.row_start(c, i, b) + q0..];
                    for (d, v) in dst.iter_mut().zip(row[j0..].iter().step_by(s)) {
                        *d = *v;
                    }
                }
            }
        }
    }

    /// Reads the image gradient (`[C, H, W]`) out of its phase layout.
    fn gather(&self, dq: &[f32], dx: &mut [f32]) {
        let (g, s) = (self.g, self.g.stride);
        for (c, plane) in dx.chunks_mut(g.height * g.width).enumerate() {
            for (i, row) in plane.chunks_mut(g.width).enumerate() {
                for b in 0..s {
                    let Some((j0, q0)) = self.phase_columns(b) else {
                        continue;
                    };
                    let src = &dq[self.row_start(c, i, b) + q0..];
                    for (d, v) in row[j0..].iter_mut().step_by(s).zip(src) {
                        *d = *v;
                    }
                }
            }
        }
    }

    /// `W[:, :, ki, kj]` (`[C_out, C]`) of a `[C_out, C, k, k]` weight.
    fn weight_tap<'a>(&self, w: &'a [f32], c_out: usize, ki: usize, kj: usize) -> Matrix<'a> {
        let (c, kk) = (self.g.channels, self.g.kernel * self.g.kernel);
        Matrix::strided(&w[ki * self.g.kernel + kj..], c_out, c, c * kk, kk)
    }

    /// Tap `(ki, kj)`'s `[C, H_out·Wq]` view of an image in this layout.
    fn input_tap<'a>(&self, xq: &'a [f32], ki: usize, kj: usize) -> Matrix<'a> {
        let (c, wide) = (self.g.channels, self.wide());
        Matrix::strided(&xq[self.tap(ki, kj)..], c, wide, self.plane, 1)
    }

    /// Scratch values [`Phases::forward`] and [`Phases::backward`] need per
    /// call (`C_out · H_out·Wq`).
    pub(crate) fn scratch_len(&self, c_out: usize) -> usize {
        c_out * self.wide()
    }

    /// One image's output `[C_out, H_out, W_out]` into `out`: `bias` plus
    /// every tap's product, from the image `xq` in this layout.
    pub(crate) fn forward(
        &self,
        w: &[f32],
        bias: &[f32],
        xq: &[f32],
        scratch: &mut [f32],
        out: &mut [f32],
    ) {
        let (k, c_out) = (self.g.kernel, bias.len());
        let (wide, wo) = (self.wide(), self.g.out_width());
        let y = &mut scratch[..c_out * wide];
        for ki in 0..k {
            for kj in 0..k {
                let first = ki == 0 && kj == 0;
                let (a, b) = (
                    self.weight_tap(w, c_out, ki, kj),
                    self.input_tap(xq, ki, kj),
                );
                gemm_into(y, !first, a, b);
            }
        }
        for ((out, y), b) in out
            .chunks_mut(self.g.positions())
            .zip(y.chunks(wide))
            .zip(bias)
        {
            for (out, y) in out.chunks_mut(wo).zip(y.chunks(self.row)) {
                for (o, v) in out.iter_mut().zip(y) {
                    *o = v + b;
                }
            }
        }
    }

    /// One image's gradients from its output gradient `grad` (`[C_out,
    /// H_out·W_out]`): adds `G · X_tapᵀ` onto `weight_taps` (`k·k` blocks
    /// of `[C_out, C]`, tap-major), and writes the input gradient `[C, H,
    /// W]` into `dx` (using `dq`, `image_len` values, as scratch).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn backward(
        &self,
        w: &[f32],
        c_out: usize,
        xq: &[f32],
        grad: &[f32],
        scratch: &mut [f32],
        weight_taps: Option<&mut [f32]>,
        input: Option<(&mut [f32], &mut [f32])>,
    ) {
        let (k, c) = (self.g.kernel, self.g.channels);
        let (wide, wo) = (self.wide(), self.g.out_width());
        // G widened to rows of Wq, zero in the unused columns.
        let g_wide = &mut scratch[..c_out * wide];
        for (dst, src) in g_wide.chunks_mut(wide).zip(grad.chunks(self.g.positions())) {
            for (dst, src) in dst.chunks_mut(self.row).zip(src.chunks(wo)) {
                dst[..wo].copy_from_slice(src);
                dst[wo..].fill(0.0);
            }
        }
        let g_wide = Matrix::row_major(g_wide, c_out, wide);
        if let Some(taps) = weight_taps {
            for (t, tap) in taps.chunks_mut(c_out * c).enumerate() {
                let (ki, kj) = (t / k, t % k);
                let x_t = Matrix::strided(&xq[self.tap(ki, kj)..], wide, c, 1, self.plane);
                gemm_into(tap, true, g_wide, x_t);
            }
        }
        if let Some((dq, dx)) = input {
            dq.fill(0.0);
            for ki in 0..k {
                for kj in 0..k {
                    let (kk, cc) = (k * k, c * k * k);
                    let w_t = Matrix::strided(&w[ki * k + kj..], c, c_out, kk, cc);
                    let start = self.tap(ki, kj);
                    gemm_into_rows(&mut dq[start..], self.plane, true, w_t, g_wide);
                }
            }
            self.gather(dq, dx);
        }
    }

    /// Adds tap-major weight gradients (`k·k` blocks of `[C_out, C]`) onto
    /// a `[C_out, C, k, k]` gradient.
    pub(crate) fn add_taps(&self, taps: &[f32], c_out: usize, dw: &mut [f32]) {
        let (k, c) = (self.g.kernel, self.g.channels);
        for (t, tap) in taps.chunks(c_out * c).enumerate() {
            for (oc, v) in tap.iter().enumerate() {
                dw[oc * k * k + t] += v;
            }
        }
    }
}
