//! Delta rows while the DRT build accumulates them: [`RowsBySource`] (per source, per global
//! texel row, f64 values; both keys ordered, so packing is deterministic), [`add_row`], and
//! [`RowMajor`], a matrix copied row-major so a ray hit reads one contiguous row.

use std::collections::BTreeMap;

use faer::Mat;

use crate::bake::drt::lit_source::LitSource;

/// Rows of one target, keyed by (source kind, source index) then global texel row.
pub type RowsBySource = BTreeMap<LitSource, BTreeMap<u32, Vec<f64>>>;

/// Accumulates `weight · row` into `map[source][global_row]`.
pub fn add_row(map: &mut RowsBySource, source: LitSource, row: u32, values: &[f64], weight: f64) {
    let acc = map
        .entry(source)
        .or_default()
        .entry(row)
        .or_insert_with(|| vec![0.0; values.len()]);
    for (a, v) in acc.iter_mut().zip(values) {
        *a += weight * v;
    }
}

/// A matrix copied row-major, so a row is a contiguous slice.
pub struct RowMajor {
    cols: usize,
    data: Vec<f64>,
}

impl RowMajor {
    pub fn of(m: &Mat<f64>) -> RowMajor {
        // faer's blocked transpose, then its columns (m's rows) one after another: reading m
        // a row at a time strides through memory (a tenth of a second for the maze's ten L_imp).
        let t = m.transpose().to_owned();
        let mut data = Vec::with_capacity(m.nrows() * m.ncols());
        for i in 0..t.ncols() {
            data.extend_from_slice(t.col_as_slice(i));
        }
        RowMajor {
            cols: m.ncols(),
            data,
        }
    }

    pub fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }
}
