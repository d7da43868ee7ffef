//! [`LitSource`]: an object whose direct light the client holds as coefficients — a block
//! (its `b`) or a DRT clutter object (its `c`). Delta rows, gathers, SH responses and probe rows
//! are all keyed by it; a bundle names it as a [`DeltaSource`] (which may also be a texel range
//! of direct light, a source no ray lands on).
//!
//! Invariant: the derived order puts every block before every clutter object, each by index —
//! the order the bake sums and packs rows in, so changing it changes bundle bytes.

use lightfarm_proto::bundle::DeltaSource;

/// A block (index in the scene's blocks) or a clutter object (index in the DRT clutter list).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LitSource {
    Block(u32),
    Clutter(u32),
}

impl From<LitSource> for DeltaSource {
    fn from(source: LitSource) -> DeltaSource {
        match source {
            LitSource::Block(b) => DeltaSource::Block(b),
            LitSource::Clutter(c) => DeltaSource::Clutter(c),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_come_before_clutter_each_by_index() {
        let mut v = vec![
            LitSource::Clutter(0),
            LitSource::Block(7),
            LitSource::Clutter(2),
            LitSource::Block(1),
        ];
        v.sort();
        assert_eq!(
            v,
            [
                LitSource::Block(1),
                LitSource::Block(7),
                LitSource::Clutter(0),
                LitSource::Clutter(2)
            ]
        );
        assert_eq!(
            DeltaSource::from(LitSource::Clutter(2)),
            DeltaSource::Clutter(2)
        );
    }
}
