//! `--hex` input of `ima decode`: hex text to bytes.

use anyhow::{Context, Result, bail};

/// Parse hex text: tokens split by whitespace or commas, optional `0x` prefix, pairs of digits.
pub fn parse_hex(text: &str) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    for token in text.split(|c: char| c.is_whitespace() || c == ',') {
        if token.is_empty() {
            continue;
        }
        let t = token
            .strip_prefix("0x")
            .or_else(|| token.strip_prefix("0X"))
            .unwrap_or(token);
        // Digits only: `from_str_radix` alone would take a sign ("+1"), and a bare "0x" is
        // no byte at all.
        if let Some(c) = t.chars().find(|c| !c.is_ascii_hexdigit()) {
            bail!("hex token {token:?}: {c:?} is not a hex digit");
        }
        if t.is_empty() {
            bail!("hex token {token:?} has no digits");
        }
        if t.len() % 2 != 0 {
            bail!("hex token {token:?} has an odd number of digits");
        }
        for i in (0..t.len()).step_by(2) {
            let pair = t.get(i..i + 2).context("hex token")?;
            out.push(u8::from_str_radix(pair, 16).with_context(|| format!("bad hex {pair:?}"))?);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_parser_accepts_common_forms_and_rejects_odd_digits() {
        assert_eq!(
            parse_hex("FA fb,0x03 0000").unwrap(),
            vec![0xFA, 0xFB, 3, 0, 0]
        );
        assert!(parse_hex("F").is_err());
        assert!(parse_hex("zz").is_err());
        // Found by a new user: a sign, a bare prefix, a doubled prefix, non-ASCII.
        for bad in ["+1", "fa+b", "0x", "0x0x", "é1"] {
            let e = format!("{:#}", parse_hex(bad).unwrap_err());
            assert!(e.contains(&format!("{bad:?}")), "{bad}: {e}");
        }
    }
}
