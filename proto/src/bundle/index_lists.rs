//! Texel index lists of the DRT section in their packed form (format 2.7, section kind 22).
//!
//! A DRT section holds several lists of texel indices: each delta entry's rows, the buried
//! texels, the exact gather's rows and row starts, the replaced texels, the tiles' starts and
//! texels. Written as `u32s` (kinds 13, 20 and 21) they cost four bytes an index, and zstd
//! finds little in them: an ascending run `1000, 1001, 1002, …` repeats no byte pattern. Kind 22
//! writes every one of them as `n:u64 len:u64` then `len` bytes of LEB128 varints, one per
//! index: the index minus the one before it minus 1 (the first: minus −1), zigzag-mapped so a
//! step back (a new tile's first texel) codes too. An ascending run is a run of zero bytes, and
//! any list of u32 round-trips, ascending or not.
//!
//! Measured on the 80-block level of seed 4 at T=8 (`gen_level.py --blocks 80 --seed 4
//! --dynamic 0`), each kind of list alone through zstd at level 9, `u32s` → packed: the tiles'
//! texels 27,211 → 313 B, their starts 6,131 → 22 B, the gather's row starts 8,756 → 3,404 B,
//! the 443 delta entries' rows (34,871 indices, with their headers) 26,634 → 5,898 B. The
//! whole DRT section: 1,309,251 → 1,246,205 B (`docs/bundle-format.md`, kind 22).
//!
//! Invariant: reading never panics and never allocates more indices than the bytes present
//! can hold (every index takes at least one byte).

use crate::wire::{push_varint, Reader, WireError, Writer};

/// How a DRT section stores its texel index lists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum IndexLists {
    /// `u32s` (kinds 13, 20, 21).
    Plain,
    /// Zigzag varints of the steps (kind 22, module doc).
    Packed,
}

/// Writes `list` in `form`.
pub(super) fn write_index_list(w: &mut Writer, list: &[u32], form: IndexLists) {
    match form {
        IndexLists::Plain => w.u32s(list),
        IndexLists::Packed => {
            let mut bytes = Vec::with_capacity(list.len());
            let mut previous = -1i64;
            for &x in list {
                let step = x as i64 - previous - 1;
                previous = x as i64;
                // Zigzag: 0, −1, 1, −2, … → 0, 1, 2, 3, …
                push_varint(&mut bytes, ((step << 1) ^ (step >> 63)) as u64);
            }
            w.u64(list.len() as u64);
            w.u64(bytes.len() as u64);
            w.bytes.extend_from_slice(&bytes);
        }
    }
}

/// Reads a list [`write_index_list`] wrote in `form`.
pub(super) fn read_index_list(r: &mut Reader, form: IndexLists) -> Result<Vec<u32>, WireError> {
    match form {
        IndexLists::Plain => r.u32s(),
        IndexLists::Packed => {
            let invalid = |m: &str| WireError::Invalid(format!("packed index list: {m}"));
            let n = r.u64()?;
            let len = r.u64()?;
            if len > r.remaining() as u64 || n > len {
                return Err(invalid("fewer bytes than indices"));
            }
            let mut bytes = Reader::new(r.take(len as usize)?);
            let mut list = Vec::with_capacity(n as usize);
            let mut previous = -1i64;
            for _ in 0..n {
                // A step of a u32 list zigzags to under 2^34: five bytes at most.
                let v = bytes.varint()?;
                let step = (v >> 1) as i64 ^ -((v & 1) as i64);
                let x = previous + 1 + step;
                let x = u32::try_from(x).map_err(|_| invalid("index outside u32"))?;
                list.push(x);
                previous = x as i64;
            }
            if bytes.remaining() != 0 {
                return Err(invalid("trailing bytes"));
            }
            Ok(list)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn packed(list: &[u32]) -> Vec<u8> {
        let mut w = Writer::new();
        write_index_list(&mut w, list, IndexLists::Packed);
        w.bytes
    }

    #[test]
    fn an_ascending_run_takes_one_zero_byte_an_index() {
        let run: Vec<u32> = (1000..1100).collect();
        let bytes = packed(&run);
        // n, len, then the first index's step (1000 → zigzag 2000: two bytes) and 99 zeros.
        assert_eq!(bytes.len(), 16 + 2 + 99);
        assert!(bytes[18..].iter().all(|&b| b == 0));
        assert_eq!(
            read_index_list(&mut Reader::new(&bytes), IndexLists::Packed).unwrap(),
            run
        );
    }

    #[test]
    fn extremes_and_steps_back_round_trip() {
        let list = vec![u32::MAX, 0, u32::MAX, 5, 5, 4, 0, 0];
        let bytes = packed(&list);
        assert_eq!(
            read_index_list(&mut Reader::new(&bytes), IndexLists::Packed).unwrap(),
            list
        );
    }

    #[test]
    fn a_count_larger_than_its_bytes_is_refused_before_allocating() {
        let mut w = Writer::new();
        w.u64(u64::MAX);
        w.u64(3);
        w.bytes.extend_from_slice(&[0, 0, 0]);
        assert!(read_index_list(&mut Reader::new(&w.bytes), IndexLists::Packed).is_err());
    }

    #[test]
    fn an_index_past_u32_is_refused() {
        // u32::MAX twice: the second is a step of −1, one byte 1; made 0 it is u32::MAX + 1.
        let mut bytes = packed(&[u32::MAX, u32::MAX]);
        let last = bytes.len() - 1;
        assert_eq!(bytes[last], 1);
        bytes[last] = 0;
        assert!(read_index_list(&mut Reader::new(&bytes), IndexLists::Packed).is_err());
    }

    proptest! {
        #[test]
        fn any_list_round_trips(list in proptest::collection::vec(any::<u32>(), 0..200)) {
            let bytes = packed(&list);
            prop_assert_eq!(
                read_index_list(&mut Reader::new(&bytes), IndexLists::Packed).unwrap(),
                list
            );
        }

        #[test]
        fn reading_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = read_index_list(&mut Reader::new(&bytes), IndexLists::Packed);
        }
    }
}
