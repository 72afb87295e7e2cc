//! Text encodings of OBJ and MTL files, which have no declared encoding: real files are UTF-8,
//! ASCII or Latin-1 (Windows exporters write material and object names in the local code page).

/// The bytes as UTF-8: unchanged when they already are, else read as Latin-1 (ISO 8859-1, each
/// byte one character), so that names in an OBJ and its MTL, converted the same way, still
/// match.
pub(crate) fn to_utf8(bytes: Vec<u8>) -> Vec<u8> {
    match String::from_utf8(bytes) {
        Ok(s) => s.into_bytes(),
        Err(e) => e
            .into_bytes()
            .iter()
            .map(|&b| b as char)
            .collect::<String>()
            .into_bytes(),
    }
}

/// A material name no MTL file defines: `usemtl` without a name selects it, so that the
/// faces that follow get the default material (tobj rejects the whole file otherwise).
const NO_MATERIAL: &str = "usemtl \u{1}oxray-default-material";

/// Rewrites OBJ lines that tobj would reject although other readers accept them: `usemtl`
/// without a name.
pub(crate) fn fix_obj(bytes: Vec<u8>) -> Vec<u8> {
    let bare = |l: &[u8]| {
        let t = l.trim_ascii();
        t == b"usemtl"
    };
    if !bytes.split(|&b| b == b'\n').any(bare) {
        return bytes;
    }
    let mut out = Vec::with_capacity(bytes.len() + 64);
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if i > 0 {
            out.push(b'\n');
        }
        if bare(line) {
            out.extend_from_slice(NO_MATERIAL.as_bytes());
        } else {
            out.extend_from_slice(line);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latin1_becomes_utf8_and_utf8_is_kept() {
        assert_eq!(to_utf8(b"caf\xe9".to_vec()), "café".as_bytes());
        assert_eq!(to_utf8("café".as_bytes().to_vec()), "café".as_bytes());
    }

    #[test]
    fn bare_usemtl_selects_no_material() {
        let fixed = fix_obj(b"v 0 0 0\nusemtl\r\nf 1 1 1\n".to_vec());
        let text = String::from_utf8(fixed).unwrap();
        assert!(text.contains("usemtl \u{1}oxray"), "{text}");
        assert!(text.ends_with("f 1 1 1\n"));
    }
}
