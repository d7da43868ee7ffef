//! The GLB container (glTF 2.0 binary, §4.4 of the spec): a 12-byte header (`glTF`, version 2,
//! total length), a JSON chunk padded with spaces and a BIN chunk padded with zeros, both to
//! 4 bytes, all integers little-endian. Written by hand: it is three length fields and two
//! paddings, not worth a dependency.

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const JSON_CHUNK: u32 = 0x4E4F_534A; // "JSON"
const BIN_CHUNK: u32 = 0x004E_4942; // "BIN\0"

fn padded(mut bytes: Vec<u8>, pad: u8) -> Vec<u8> {
    while bytes.len() % 4 != 0 {
        bytes.push(pad);
    }
    bytes
}

/// The GLB bytes of `json` (a glTF document whose buffer 0 has no `uri`) and its buffer.
pub fn write(json: &serde_json::Value, binary: &[u8]) -> Vec<u8> {
    let json = padded(serde_json::to_vec(json).expect("JSON serialises"), b' ');
    let binary = padded(binary.to_vec(), 0);
    let total = 12
        + 8
        + json.len()
        + if binary.is_empty() {
            0
        } else {
            8 + binary.len()
        };
    let mut out = Vec::with_capacity(total);
    for word in [MAGIC, 2, total as u32, json.len() as u32, JSON_CHUNK] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    out.extend_from_slice(&json);
    if !binary.is_empty() {
        out.extend_from_slice(&(binary.len() as u32).to_le_bytes());
        out.extend_from_slice(&BIN_CHUNK.to_le_bytes());
        out.extend_from_slice(&binary);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_and_chunks_are_aligned_and_counted() {
        let doc = serde_json::json!({ "asset": { "version": "2.0" } });
        let glb = write(&doc, &[1, 2, 3]);
        let word = |at: usize| u32::from_le_bytes(glb[at..at + 4].try_into().unwrap());
        assert_eq!(&glb[..4], b"glTF");
        assert_eq!((word(4), word(8) as usize), (2, glb.len()));
        let json_len = word(12) as usize;
        assert_eq!(json_len % 4, 0);
        assert_eq!(&glb[16..20], b"JSON");
        let text = std::str::from_utf8(&glb[20..20 + json_len]).unwrap();
        assert_eq!(
            serde_json::from_str::<serde_json::Value>(text).unwrap(),
            doc
        );
        let bin_at = 20 + json_len;
        assert_eq!(word(bin_at), 4);
        assert_eq!(&glb[bin_at + 4..bin_at + 8], b"BIN\0");
        assert_eq!(&glb[bin_at + 8..], &[1, 2, 3, 0]);
    }
}
