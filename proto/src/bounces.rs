//! How many bounces of indirect light a result sums: `--bounces N|all` on the CLI
//! (`eval`, `reference`, `frame-time`, `bench`, `export`) and `bounces` in the service's API.
//!
//! Bounce 1 is the papers' one-bounce indirect light (direct light reflected once);
//! bounce k is light that left a light source and was reflected k times before reaching the
//! texel. `All` sums every bounce (the fixed point `I = A·(L_d + I)` of the one-bounce
//! operator `A`), as path tracers and commercial bakers do.
//!
//! Invariant: a `Fixed` count is at least 1 (checked by [`BounceCount::fixed`] and the parser).

use std::fmt;
use std::str::FromStr;

/// The number of bounces of indirect light, or all of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BounceCount {
    /// Exactly this many bounces (≥ 1); `Fixed(1)` is the papers' one-bounce light.
    Fixed(u32),
    /// Every bounce (the default).
    #[default]
    All,
}

/// Why a bounce count could not be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("bounces: expected a whole number ≥ 1, \"one\" or \"all\", got \"{0}\"")]
pub struct BounceCountError(pub String);

impl BounceCount {
    /// One bounce: the papers' light.
    pub const ONE: BounceCount = BounceCount::Fixed(1);

    /// `Fixed(n)`, or an error for 0.
    pub fn fixed(n: u32) -> Result<BounceCount, BounceCountError> {
        if n == 0 {
            Err(BounceCountError(n.to_string()))
        } else {
            Ok(BounceCount::Fixed(n))
        }
    }

    /// The bounce count as a path depth limit: `None` for all bounces.
    pub fn limit(self) -> Option<u32> {
        match self {
            BounceCount::Fixed(n) => Some(n),
            BounceCount::All => None,
        }
    }
}

impl FromStr for BounceCount {
    type Err = BounceCountError;

    fn from_str(s: &str) -> Result<BounceCount, BounceCountError> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("all") {
            return Ok(BounceCount::All);
        }
        if t.eq_ignore_ascii_case("one") {
            return Ok(BounceCount::ONE);
        }
        match t.parse::<u32>() {
            Ok(n) if n >= 1 => Ok(BounceCount::Fixed(n)),
            _ => Err(BounceCountError(s.to_string())),
        }
    }
}

impl fmt::Display for BounceCount {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BounceCount::Fixed(n) => write!(f, "{n}"),
            BounceCount::All => f.write_str("all"),
        }
    }
}

impl serde::Serialize for BounceCount {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            BounceCount::Fixed(n) => s.serialize_u32(*n),
            BounceCount::All => s.serialize_str("all"),
        }
    }
}

impl<'de> serde::Deserialize<'de> for BounceCount {
    /// Accepts `"all"`, a whole number ≥ 1, or the same number as a string.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<BounceCount, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Number(u64),
            Text(String),
        }
        let parsed = match Raw::deserialize(d)? {
            Raw::Number(n) => u32::try_from(n)
                .ok()
                .filter(|&n| n >= 1)
                .map(BounceCount::Fixed)
                .ok_or_else(|| BounceCountError(n.to_string())),
            Raw::Text(t) => t.parse(),
        };
        parsed.map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_round_trip() {
        for (text, value) in [
            ("1", BounceCount::ONE),
            ("7", BounceCount::Fixed(7)),
            ("all", BounceCount::All),
            ("ALL", BounceCount::All),
            ("one", BounceCount::ONE),
        ] {
            let parsed: BounceCount = text.parse().unwrap();
            assert_eq!(parsed, value);
            assert_eq!(parsed.to_string().parse::<BounceCount>().unwrap(), value);
        }
        for bad in ["0", "-1", "", "two", "1.5"] {
            let e = bad.parse::<BounceCount>().unwrap_err();
            assert!(e.to_string().contains("bounces"), "{e}");
        }
        assert!(BounceCount::fixed(0).is_err());
        assert_eq!(BounceCount::default(), BounceCount::All);
        assert_eq!(BounceCount::All.limit(), None);
        assert_eq!(BounceCount::Fixed(3).limit(), Some(3));
    }

    #[test]
    fn serde_takes_numbers_and_all() {
        let v: Vec<BounceCount> = serde_json::from_str(r#"[1, "all", "3"]"#).unwrap();
        assert_eq!(
            v,
            [BounceCount::ONE, BounceCount::All, BounceCount::Fixed(3)]
        );
        assert_eq!(serde_json::to_string(&v).unwrap(), r#"[1,"all",3]"#);
        assert!(serde_json::from_str::<BounceCount>("0").is_err());
    }
}
