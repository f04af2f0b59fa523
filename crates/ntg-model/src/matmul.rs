//! A checked, safe front to the `gemm` crate's `f32` matrix product, for
//! kernels that write into buffers they own (the convolution of `conv.rs`).
//!
//! burn's `flex` backend multiplies through the same crate, but every call
//! returns a freshly allocated, zero-filled and then re-aligned output
//! tensor. At the frame encoder's sizes (outputs of 4–33 MB) those
//! allocations, page faults and copies cost about a fifth of a training
//! step. Here the caller passes the destination, and a product can
//! accumulate into it.
//!
//! This is the only module of the workspace with `unsafe` code: one call to
//! `gemm::gemm`, behind [`Matrix`] views whose every index is checked to lie
//! inside its slice before the call.

/// A read-only strided view of an `f32` matrix: element `(i, j)` is
/// `data[i·row_stride + j·col_stride]`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Matrix<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

impl<'a> Matrix<'a> {
    /// A row-major `[rows, cols]` matrix at the start of `data`.
    pub(crate) fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self::strided(data, rows, cols, cols, 1)
    }

    /// The transpose of the row-major `[cols, rows]` matrix at the start of
    /// `data`, as a `[rows, cols]` view.
    pub(crate) fn transposed(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self::strided(data, rows, cols, 1, rows)
    }

    /// A view with explicit strides.
    ///
    /// # Panics
    /// If an element of the view lies outside `data`.
    pub(crate) fn strided(
        data: &'a [f32],
        rows: usize,
        cols: usize,
        row_stride: usize,
        col_stride: usize,
    ) -> Self {
        assert!(
            rows == 0 || cols == 0 || last_index(rows, cols, row_stride, col_stride) < data.len(),
            "matrix view [{rows}, {cols}] (strides {row_stride}, {col_stride}) exceeds {} values",
            data.len()
        );
        Matrix {
            data,
            rows,
            cols,
            row_stride,
            col_stride,
        }
    }
}

/// The largest index a `[rows, cols]` strided view reads.
fn last_index(rows: usize, cols: usize, row_stride: usize, col_stride: usize) -> usize {
    (rows - 1) * row_stride + (cols - 1) * col_stride
}

/// `dst = a · b` (or `dst += a · b` with `accumulate`), `dst` row-major
/// `[a.rows, b.cols]` at the start of the slice, on the calling thread.
///
/// # Panics
/// If the inner dimensions differ or `dst` is too short.
pub(crate) fn gemm_into(dst: &mut [f32], accumulate: bool, a: Matrix<'_>, b: Matrix<'_>) {
    gemm_into_rows(dst, b.cols, accumulate, a, b);
}

/// [`gemm_into`] with the destination's rows `dst_row_stride` values apart
/// (`≥ b.cols`; the values between rows are left alone).
///
/// # Panics
/// If the inner dimensions differ, the stride is below `b.cols` or `dst`
/// is too short.
pub(crate) fn gemm_into_rows(
    dst: &mut [f32],
    dst_row_stride: usize,
    accumulate: bool,
    a: Matrix<'_>,
    b: Matrix<'_>,
) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert_eq!(
        k, b.rows,
        "matrix product: inner dimensions {k} and {}",
        b.rows
    );
    assert!(
        dst_row_stride >= n,
        "matrix product: row stride {dst_row_stride} below {n} columns"
    );
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        last_index(m, n, dst_row_stride, 1) < dst.len(),
        "matrix product: destination of {} values for [{m}, {n}] (row stride {dst_row_stride})",
        dst.len()
    );
    if k == 0 {
        if !accumulate {
            for row in dst.chunks_mut(dst_row_stride).take(m) {
                row[..n].fill(0.0);
            }
        }
        return;
    }
    let stride = |s: usize| isize::try_from(s).expect("matrix stride fits isize");
    // SAFETY: `Matrix::strided` checked that every element `(i, j)` of `a`
    // (i < m, j < k) and of `b` (i < k, j < n) lies inside its slice, and
    // the assertion above that every element `(i, j)` of `dst` (i < m,
    // j < n, at i·dst_row_stride + j) does. `dst` is a unique borrow, so
    // it aliases neither input, and with `dst_row_stride ≥ n` no two of
    // its elements coincide. With `read_dst` false, `gemm` never reads
    // `dst` (its `alpha` is ignored); with it, `dst` is initialised `f32`s.
    #[allow(unsafe_code)]
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            stride(dst_row_stride),
            accumulate,
            a.data.as_ptr(),
            stride(a.col_stride),
            stride(a.row_stride),
            b.data.as_ptr(),
            stride(b.col_stride),
            stride(b.row_stride),
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: Matrix<'_>, b: Matrix<'_>) -> Vec<f32> {
        let at = |m: &Matrix<'_>, i: usize, j: usize| m.data[i * m.row_stride + j * m.col_stride];
        let mut out = vec![0.0f32; a.rows * b.cols];
        for i in 0..a.rows {
            for j in 0..b.cols {
                out[i * b.cols + j] = (0..a.cols).map(|p| at(&a, i, p) * at(&b, p, j)).sum();
            }
        }
        out
    }

    /// Products of plain and transposed views against the naive loop, and
    /// accumulation onto what `dst` holds.
    #[test]
    fn matches_the_naive_product_and_accumulates() {
        let (m, k, n) = (5, 7, 3);
        let a_data: Vec<f32> = (0..m * k).map(|i| ((i * 7) % 11) as f32 - 5.0).collect();
        let b_data: Vec<f32> = (0..k * n).map(|i| ((i * 5) % 13) as f32 - 6.0).collect();
        let b_t_data: Vec<f32> = (0..n * k).map(|i| b_data[(i % k) * n + i / k]).collect();
        let a = Matrix::row_major(&a_data, m, k);
        for b in [
            Matrix::row_major(&b_data, k, n),
            Matrix::transposed(&b_t_data, k, n),
        ] {
            let expected = naive(a, b);
            let mut dst = vec![f32::NAN; m * n];
            gemm_into(&mut dst, false, a, b);
            assert_eq!(dst, expected);
            gemm_into(&mut dst, true, a, b);
            let doubled: Vec<f32> = expected.iter().map(|v| 2.0 * v).collect();
            assert_eq!(dst, doubled);
        }
    }

    /// A destination with gaps between its rows: the gaps keep their
    /// values.
    #[test]
    fn a_strided_destination_leaves_the_gaps_alone() {
        let (a, b) = ([1.0f32, 2.0, 3.0, 4.0], [1.0f32, 0.0, 0.0, 1.0]);
        let mut dst = [9.0f32; 7];
        gemm_into_rows(
            &mut dst,
            3,
            false,
            Matrix::row_major(&a, 2, 2),
            Matrix::row_major(&b, 2, 2),
        );
        assert_eq!(dst, [1.0, 2.0, 9.0, 3.0, 4.0, 9.0, 9.0]);
    }

    #[test]
    #[should_panic(expected = "exceeds")]
    fn a_view_past_its_slice_is_refused() {
        let data = [0.0f32; 11];
        let _ = Matrix::row_major(&data, 3, 4);
    }

    #[test]
    #[should_panic(expected = "destination")]
    fn a_short_destination_is_refused() {
        let (a, b) = ([1.0f32; 6], [1.0f32; 6]);
        let mut dst = [0.0f32; 3];
        gemm_into(
            &mut dst,
            false,
            Matrix::row_major(&a, 2, 3),
            Matrix::row_major(&b, 3, 2),
        );
    }
}
