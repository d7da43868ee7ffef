//! The bake's matrices (faer `Mat<f64>`, where precision decides) as the bundle's (f32,
//! row-major, where bandwidth decides): the one conversion every stage that ships an operator
//! uses; and the f32 ↔ f64 conversions of what the bake holds in f32 because a large level's
//! memory decides (the lightfield operators and `T_prop`), computed with in f64.

use faer::Mat;
use lightfarm_proto::bundle::Matrix;

/// `m` in f64 (exact), for the products that read a matrix held in f32.
pub fn widen(m: &Mat<f32>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| f64::from(m[(i, j)]))
}

/// A bundle matrix (f32, row-major) in f64 (exact), for products that read what a bundle ships.
pub fn from_matrix(m: &Matrix) -> Mat<f64> {
    let c = m.cols as usize;
    Mat::from_fn(m.rows as usize, c, |i, j| f64::from(m.data[i * c + j]))
}

/// `‖m‖_F²`, summed column by column (the order every truncation by energy here uses).
pub fn energy(m: &Mat<f64>) -> f64 {
    let mut e = 0.0;
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            e += m[(i, j)] * m[(i, j)];
        }
    }
    e
}

/// `m` rounded to f32, to be held where memory decides.
pub fn narrow(m: &Mat<f64>) -> Mat<f32> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32)
}

/// A bake matrix (f64, or f32 where the bake holds it so) as a bundle matrix (f32, row-major).
pub fn to_matrix<T: Copy>(m: &Mat<T>) -> Matrix
where
    f64: From<T>,
{
    let mut data = Vec::with_capacity(m.nrows() * m.ncols());
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            data.push(f64::from(m[(i, j)]) as f32);
        }
    }
    Matrix {
        rows: m.nrows() as u32,
        cols: m.ncols() as u32,
        data,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn rows_stay_rows() {
        let m = faer::mat![[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]];
        let out = super::to_matrix(&m);
        assert_eq!((out.rows, out.cols), (2, 3));
        assert_eq!(out.data, [1.0, 2.0, 3.0, 4.0, 5.0, 6.5]);
    }
}
