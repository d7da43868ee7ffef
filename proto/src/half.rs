//! IEEE 754 binary16 (half precision) ↔ f32, for compact storage of baked values.
//!
//! Invariant: [`f16_from_f32`] rounds to nearest, ties to even; values beyond the half range
//! become ±infinity, NaN stays NaN; [`f32_from_f16`] is exact.

/// The binary16 bits nearest to `x`.
pub fn f16_from_f32(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exp = ((bits >> 23) & 0xff) as i32;
    let man = bits & 0x007f_ffff;
    if exp == 0xff {
        // Infinity or NaN (keep a quiet NaN).
        return sign | 0x7c00 | if man != 0 { 0x0200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal half (or zero).
        if e < -10 {
            return sign;
        }
        let m = man | 0x0080_0000;
        let shift = (14 - e) as u32;
        let half = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let mid = 1u32 << (shift - 1);
        let round = rem > mid || (rem == mid && half & 1 == 1);
        return sign | (half + round as u32) as u16;
    }
    let half = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    let round = rem > 0x1000 || (rem == 0x1000 && half & 1 == 1);
    // A carry out of the mantissa correctly bumps the exponent (up to infinity).
    sign | (half + round as u32) as u16
}

/// The f32 value of binary16 bits.
pub fn f32_from_f16(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x03ff) as u32;
    let bits = match exp {
        0 if man == 0 => sign,
        0 => {
            // Subnormal: normalise.
            let mut e = 127 - 15 + 1;
            let mut m = man;
            while m & 0x0400 == 0 {
                m <<= 1;
                e -= 1;
            }
            sign | ((e as u32) << 23) | ((m & 0x03ff) << 13)
        }
        0x1f => sign | 0x7f80_0000 | (man << 13),
        _ => sign | ((exp + 127 - 15) << 23) | (man << 13),
    };
    f32::from_bits(bits)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_half_round_trips_and_rounding_is_to_nearest() {
        for h in 0..=u16::MAX {
            let x = f32_from_f16(h);
            if x.is_nan() {
                assert!(f32_from_f16(f16_from_f32(x)).is_nan());
                continue;
            }
            assert_eq!(f16_from_f32(x), h, "{h:#06x} -> {x}");
        }
        for x in [0.1f32, -0.3, 1.0e-6, 1.2345, 65504.0, 1.0e-8, -2.5e-5] {
            let back = f32_from_f16(f16_from_f32(x));
            // Relative error at most 2^-11 for normal halves; absolute 2^-25 for subnormals.
            assert!(
                (back - x).abs() <= x.abs() * 4.9e-4 + 3.0e-8,
                "{x} -> {back}"
            );
        }
        assert_eq!(f32_from_f16(f16_from_f32(1.0e6)), f32::INFINITY);
    }
}
