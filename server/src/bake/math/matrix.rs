//! The bake's matrices (faer `Mat<f64>`, where precision decides) as the bundle's (f32,
//! row-major, where bandwidth decides): the one conversion every stage that ships an operator
//! uses.

use faer::Mat;
use lightfarm_proto::bundle::Matrix;

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
