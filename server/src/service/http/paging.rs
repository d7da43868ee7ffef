//! Cursor pagination of the listings (`GET /v1/bakes`, `GET /v1/scenes`): items newest first,
//! ordered by (time, id) descending, cut into pages of `limit`.
//!
//! A cursor is 80 lowercase hex digits: the last item's time (Unix seconds, the 16 hex digits
//! of its f64 bits) and its 64-digit id. The next page holds the items strictly after it in the
//! order, so a page stays right when items are added or removed between requests.
//!
//! Invariant: a bad `limit` or `cursor` is a 400 naming the parameter, never a silent default.

use super::error::ApiFailure;
use axum::http::StatusCode;

/// Items per page when the request names no `limit`.
pub const DEFAULT_LIMIT: u32 = 50;
/// The largest `limit` accepted.
pub const MAX_LIMIT: u32 = 200;

/// A position in the (time, id) descending order.
#[derive(Clone, Debug, PartialEq)]
pub struct Cursor {
    pub time_bits: u64,
    pub id: String,
}

impl Cursor {
    pub fn of(time: f64, id: &str) -> Cursor {
        Cursor {
            time_bits: time.max(0.0).to_bits(),
            id: id.to_string(),
        }
    }

    pub fn encode(&self) -> String {
        format!("{:016x}{}", self.time_bits, self.id)
    }

    pub fn parse(text: &str) -> Result<Cursor, ApiFailure> {
        let valid = text.len() == 80
            && text
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
        if !valid {
            return Err(bad_request(
                "cursor: expected the 80 hex digits of a `next` link",
            ));
        }
        let time_bits = u64::from_str_radix(&text[..16], 16).expect("checked hex");
        Ok(Cursor {
            time_bits,
            id: text[16..].to_string(),
        })
    }
}

fn bad_request(message: &str) -> ApiFailure {
    ApiFailure::new(StatusCode::BAD_REQUEST, message)
}

/// The page a listing's query asks for: its size ([`page_limit`]) and where it starts.
pub fn page_request(
    limit: Option<u32>,
    cursor: Option<&str>,
) -> Result<(usize, Option<Cursor>), ApiFailure> {
    Ok((page_limit(limit)?, cursor.map(Cursor::parse).transpose()?))
}

/// The page size a request asked for.
pub fn page_limit(limit: Option<u32>) -> Result<usize, ApiFailure> {
    match limit {
        None => Ok(DEFAULT_LIMIT as usize),
        Some(n) if (1..=MAX_LIMIT).contains(&n) => Ok(n as usize),
        Some(n) => Err(bad_request(&format!(
            "limit: {n} is outside 1..={MAX_LIMIT}"
        ))),
    }
}

/// One page of `items` (each with its time and id), newest first, after `cursor`; the cursor
/// of the next page when more items follow.
pub fn page<T>(
    mut items: Vec<(f64, String, T)>,
    cursor: Option<&Cursor>,
    limit: usize,
) -> (Vec<T>, Option<Cursor>) {
    let key = |time: f64, id: &str| (time.max(0.0).to_bits(), id.to_string());
    items.sort_by(|a, b| key(b.0, &b.1).cmp(&key(a.0, &a.1)));
    if let Some(c) = cursor {
        let after = (c.time_bits, c.id.clone());
        items.retain(|(time, id, _)| key(*time, id) < after);
    }
    let more = items.len() > limit;
    items.truncate(limit);
    let next = if more {
        items.last().map(|(time, id, _)| Cursor::of(*time, id))
    } else {
        None
    };
    (items.into_iter().map(|(_, _, item)| item).collect(), next)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(n: u8) -> String {
        format!("{n:064x}")
    }

    #[test]
    fn pages_walk_every_item_once_newest_first() {
        // Two items share a time: the id breaks the tie.
        let times = [3.0, 1.0, 2.0, 2.0, 5.0];
        let items = || -> Vec<(f64, String, u8)> {
            times
                .iter()
                .enumerate()
                .map(|(k, t)| (*t, id(k as u8), k as u8))
                .collect()
        };
        let (first, next) = page(items(), None, 2);
        assert_eq!(first, vec![4, 0]);
        let next = Cursor::parse(&next.unwrap().encode()).unwrap();
        let (second, next) = page(items(), Some(&next), 2);
        assert_eq!(second, vec![3, 2]);
        let (third, next) = page(items(), next.as_ref(), 2);
        assert_eq!(third, vec![1]);
        assert!(next.is_none());
    }

    #[test]
    fn bad_limits_and_cursors_are_refused_by_name() {
        assert_eq!(page_limit(None).unwrap(), DEFAULT_LIMIT as usize);
        assert_eq!(page_limit(Some(MAX_LIMIT)).unwrap(), MAX_LIMIT as usize);
        for bad in [0, MAX_LIMIT + 1] {
            let e = page_limit(Some(bad)).unwrap_err();
            assert_eq!(e.status, StatusCode::BAD_REQUEST);
            assert!(e.message.starts_with("limit:"), "{}", e.message);
        }
        for bad in ["", "xyz", &"A".repeat(80), &"0".repeat(79)] {
            let e = Cursor::parse(bad).unwrap_err();
            assert!(e.message.starts_with("cursor:"), "{}", e.message);
        }
    }
}
