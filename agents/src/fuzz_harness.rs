//! Fuzz-target bodies, kept in the crate so `cargo test` can replay the committed corpora
//! (`agents/tests/fuzz_corpus.rs`) and `fuzz/fuzz_targets/*.rs` stay one-liners.
#![allow(clippy::panic)]

use crate::ses::shared::SharedForm;

/// `ses_shared_form`: parse any bytes as a shared form; must never panic. When the bytes
/// parse, asserts the round trip: re-encoding succeeds, the re-encoding parses back to the
/// same form, and it equals the input except for the CRC (which fuzz builds do not check).
pub fn ses_shared_form(data: &[u8]) {
    let Ok(form) = SharedForm::decode(data) else {
        return;
    };
    let bytes = match form.to_bytes() {
        Ok(b) => b,
        Err(e) => panic!("a decoded form must re-encode: {e}"),
    };
    let again = SharedForm::decode(&bytes);
    assert_eq!(
        again.as_ref(),
        Ok(&form),
        "decode(encode(decode(x))) != decode(x)"
    );
    let body = |b: &[u8]| {
        b.len()
            .checked_sub(2)
            .and_then(|n| b.get(..n))
            .map(<[u8]>::to_vec)
    };
    assert_eq!(body(&bytes), body(data), "re-encoding changed the body");
}
