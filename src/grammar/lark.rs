//! Lark text helpers: quoting literal text so that any object or verb name reaches the grammar
//! unchanged.

use std::fmt::Write;

/// A Lark string literal matching exactly `s`.
///
/// llguidance reads Lark strings with JSON escapes and rejects raw control characters and DEL inside
/// them, so quotes and backslashes are backslash-escaped, newline, CR and tab use their short escapes,
/// every other control character is written as `\u00XX`, and all other characters stay as they are.
pub fn lark_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                // Writing into a String cannot fail.
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quotes_backslashes_and_controls_are_escaped() {
        assert_eq!(lark_string("apple"), "\"apple\"");
        assert_eq!(lark_string("a\"b"), "\"a\\\"b\"");
        assert_eq!(lark_string("a\\b"), "\"a\\\\b\"");
        assert_eq!(lark_string("a\nb\u{7f}\u{1}"), "\"a\\nb\\u007f\\u0001\"");
        assert_eq!(lark_string("café/x"), "\"café/x\"");
    }

    #[test]
    fn escaped_literals_decode_back_as_json() {
        // llguidance decodes Lark strings as JSON: the round trip through serde_json is the contract.
        for s in ["plain", "q\"uote", "back\\slash", "tab\tnl\n", "del\u{7f}", "ünï/cödé", "\\\"\\"] {
            let lit = lark_string(s);
            let back: String = serde_json::from_str(&lit).unwrap();
            assert_eq!(back, s, "literal {lit}");
        }
    }
}
