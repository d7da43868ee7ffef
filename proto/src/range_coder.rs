//! An adaptive binary range coder (the one of LZMA): [`RangeEncoder`], [`RangeDecoder`], and
//! the adaptive models they code with, [`Bit`] and [`ByteTree`], and LEB128 values coded a byte
//! at a time ([`VarintTrees`]).
//!
//! zstd codes literals with one Huffman table per block: at least a bit a byte, and blind to
//! what came before. The exact gather's hit counts are Monte Carlo noise around a mean that the
//! neighbouring texel's counts predict well; coded by a model conditioned on them the counts
//! of the 80-block level of seed 4 take 150 kB instead of zstd's 213 kB
//! (`crate::bundle::gather_model`). No crate on offer does adaptive binary coding with the
//! contexts our own code picks (`constriction` codes with models it is handed per symbol), and
//! the coder is this file: the encoder's carry handling and the decoder's normalisation are
//! LZMA's (Igor Pavlov's public-domain `LzmaEnc.c` / `LzmaDec.c`).
//!
//! Probabilities are 11-bit (`p(0) = prob / 2048`), start at one half and move a 32nd of the
//! way to each coded bit, so they stay within [31, 2017] / 2048: every decision costs at most
//! 6 bits and at least 0.022 bits, which bounds how many symbols a byte of input can decode
//! ([`MIN_BITS_PER_DECISION`]).
//!
//! Invariants: decoding what [`RangeEncoder::finish`] gave with the same sequence of models
//! gives back every bit; decoding any other bytes never panics (past the end the decoder reads
//! zeros and [`RangeDecoder::overran`] says so); the output is a pure function of the bits and
//! models coded.

use crate::wire::VARINT_MAX_BYTES;

const PROB_BITS: u32 = 11;
const PROB_ONE: u16 = 1 << PROB_BITS;
const MOVE_BITS: u32 = 5;
const TOP: u32 = 1 << 24;

/// The least a binary decision costs, in bits: −log2(2017 / 2048), the most probable a
/// [`Bit`] gets. A byte of coded input holds at most 8 / 0.022 ≈ 360 decisions.
pub const MIN_BITS_PER_DECISION: f64 = 0.022;

/// An adaptive probability that the next bit is 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bit(u16);

impl Default for Bit {
    fn default() -> Self {
        Bit(PROB_ONE / 2)
    }
}

impl Bit {
    #[inline]
    fn update(&mut self, bit: bool) {
        if bit {
            self.0 -= self.0 >> MOVE_BITS;
        } else {
            self.0 += (PROB_ONE - self.0) >> MOVE_BITS;
        }
    }
}

/// An adaptive model of a byte: a binary tree of 255 [`Bit`]s, most significant bit first.
#[derive(Clone, Debug)]
pub struct ByteTree([Bit; 256]);

impl Default for ByteTree {
    fn default() -> Self {
        ByteTree([Bit::default(); 256])
    }
}

/// Adaptive models of a LEB128 value of at most [`VARINT_MAX_BYTES`] bytes (a u32; the
/// bundle's plain varints, [`crate::wire::push_varint`], split a value the same way), one
/// [`ByteTree`] per byte position.
#[derive(Clone, Debug, Default)]
pub struct VarintTrees([ByteTree; VARINT_MAX_BYTES]);

/// Encodes bits under adaptive models into bytes.
#[derive(Debug)]
pub struct RangeEncoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
}

impl Default for RangeEncoder {
    fn default() -> Self {
        RangeEncoder {
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
            out: Vec::new(),
        }
    }
}

impl RangeEncoder {
    /// Codes `bit` with `model`'s probability, then moves the model towards it.
    #[inline]
    pub fn bit(&mut self, model: &mut Bit, bit: bool) {
        let bound = (self.range >> PROB_BITS) * model.0 as u32;
        if bit {
            self.low += bound as u64;
            self.range -= bound;
        } else {
            self.range = bound;
        }
        model.update(bit);
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Codes `byte` with `tree`.
    #[inline]
    pub fn byte(&mut self, tree: &mut ByteTree, byte: u8) {
        let mut node = 1usize;
        for i in (0..8).rev() {
            let bit = (byte >> i) & 1 == 1;
            self.bit(&mut tree.0[node], bit);
            node = 2 * node + bit as usize;
        }
    }

    /// Codes `value` as LEB128 bytes, each with its position's tree.
    pub fn varint(&mut self, trees: &mut VarintTrees, mut value: u32) {
        for tree in trees.0.iter_mut() {
            let more = value >= 0x80;
            self.byte(tree, (value & 0x7f) as u8 | if more { 0x80 } else { 0 });
            value >>= 7;
            if !more {
                return;
            }
        }
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xff00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut byte = self.cache;
            loop {
                self.out.push(byte.wrapping_add(carry));
                byte = 0xff;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = (self.low >> 24) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00ff_ffff) << 8;
    }

    /// The coded bytes (all pending ones flushed).
    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        self.out
    }
}

/// Decodes what a [`RangeEncoder`] coded, with the same models in the same order.
#[derive(Debug)]
pub struct RangeDecoder<'a> {
    bytes: &'a [u8],
    at: usize,
    range: u32,
    code: u32,
    overran: bool,
}

impl<'a> RangeDecoder<'a> {
    /// A decoder over `bytes` (its first five primed).
    pub fn new(bytes: &'a [u8]) -> RangeDecoder<'a> {
        let mut d = RangeDecoder {
            bytes,
            at: 0,
            range: u32::MAX,
            code: 0,
            overran: false,
        };
        for _ in 0..5 {
            d.code = (d.code << 8) | d.next() as u32;
        }
        d
    }

    #[inline]
    fn next(&mut self) -> u8 {
        match self.bytes.get(self.at) {
            Some(&b) => {
                self.at += 1;
                b
            }
            None => {
                self.overran = true;
                0
            }
        }
    }

    /// Whether decoding read past the end of the bytes (then what it gave is not what was
    /// coded, or the bytes were cut short).
    pub fn overran(&self) -> bool {
        self.overran
    }

    /// Whether every byte was read.
    pub fn at_end(&self) -> bool {
        self.at == self.bytes.len()
    }

    /// Decodes a bit with `model`'s probability, then moves the model towards it.
    #[inline]
    pub fn bit(&mut self, model: &mut Bit) -> bool {
        let bound = (self.range >> PROB_BITS) * model.0 as u32;
        let bit = if self.code < bound {
            self.range = bound;
            false
        } else {
            self.code -= bound;
            self.range -= bound;
            true
        };
        model.update(bit);
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next() as u32;
        }
        bit
    }

    /// Decodes a byte with `tree`.
    #[inline]
    pub fn byte(&mut self, tree: &mut ByteTree) -> u8 {
        let mut node = 1usize;
        for _ in 0..8 {
            node = 2 * node + self.bit(&mut tree.0[node]) as usize;
        }
        (node - 256) as u8
    }

    /// Decodes a value [`RangeEncoder::varint`] coded; None when its bytes go past a u32.
    pub fn varint(&mut self, trees: &mut VarintTrees) -> Option<u32> {
        let mut value = 0u64;
        for (i, tree) in trees.0.iter_mut().enumerate() {
            let byte = self.byte(tree);
            value |= ((byte & 0x7f) as u64) << (7 * i);
            if byte & 0x80 == 0 {
                return u32::try_from(value).ok();
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_skewed_source_codes_near_its_entropy() {
        // 100,000 bits with p(1) = 1/16: entropy 0.337 bits each, 4,218 bytes.
        let mut state = 12345u64;
        let bits: Vec<bool> = (0..100_000)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                (state >> 33).is_multiple_of(16)
            })
            .collect();
        let mut e = RangeEncoder::default();
        let mut m = Bit::default();
        for &b in &bits {
            e.bit(&mut m, b);
        }
        let bytes = e.finish();
        assert!(bytes.len() < 4_400, "{} bytes", bytes.len());
        let mut d = RangeDecoder::new(&bytes);
        let mut m = Bit::default();
        assert!(bits.iter().all(|&b| d.bit(&mut m) == b));
        assert!(!d.overran());
        assert!(d.at_end());
    }

    #[test]
    fn probabilities_stay_within_their_bounds() {
        let mut m = Bit::default();
        for _ in 0..10_000 {
            m.update(false);
        }
        assert_eq!(m.0, 2017);
        for _ in 0..10_000 {
            m.update(true);
        }
        assert_eq!(m.0, 31);
        // The cheapest decision is the bound MIN_BITS_PER_DECISION states.
        let cheapest = -(2017.0f64 / 2048.0).log2();
        assert!(
            (cheapest - MIN_BITS_PER_DECISION).abs() < 5e-4,
            "{cheapest}"
        );
    }

    proptest! {
        #[test]
        fn bytes_and_varints_round_trip(
            symbols in proptest::collection::vec((any::<u8>(), any::<u32>(), any::<bool>()), 0..400)
        ) {
            let (mut trees, mut varints, mut bit) =
                (ByteTree::default(), VarintTrees::default(), Bit::default());
            let mut e = RangeEncoder::default();
            for &(b, v, f) in &symbols {
                e.byte(&mut trees, b);
                e.varint(&mut varints, v);
                e.bit(&mut bit, f);
            }
            let bytes = e.finish();
            let (mut trees, mut varints, mut bit) =
                (ByteTree::default(), VarintTrees::default(), Bit::default());
            let mut d = RangeDecoder::new(&bytes);
            for &(b, v, f) in &symbols {
                prop_assert_eq!(d.byte(&mut trees), b);
                prop_assert_eq!(d.varint(&mut varints), Some(v));
                prop_assert_eq!(d.bit(&mut bit), f);
            }
            prop_assert!(!d.overran());
            prop_assert!(d.at_end());
        }

        #[test]
        fn any_bytes_decode_without_panicking(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let (mut trees, mut varints) = (ByteTree::default(), VarintTrees::default());
            let mut d = RangeDecoder::new(&bytes);
            for _ in 0..200 {
                d.byte(&mut trees);
                let _ = d.varint(&mut varints);
            }
        }
    }
}
