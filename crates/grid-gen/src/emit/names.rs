//! Turning names from a URDF into things that are safe to put in generated files: file
//! names and identifiers that cannot escape the output folder or break the code, and
//! string literals that cannot end early.

/// A lower-case identifier made of `[a-z0-9_]`, never empty, never starting with a digit,
/// never a Rust keyword. Anything else in the name becomes `_`.
pub fn identifier(name: &str) -> String {
    let mut out: String = name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, "robot_");
    }
    const KEYWORDS: &[&str] = &[
        "as", "async", "await", "break", "const", "continue", "crate", "dyn", "else", "enum", "extern", "false", "fn", "for", "gen", "if", "impl", "in", "let",
        "loop", "match", "mod", "move", "mut", "pub", "ref", "return", "self", "static", "struct", "super", "trait", "true", "type", "unsafe", "use", "where",
        "while", "_",
    ];
    if KEYWORDS.contains(&out.as_str()) {
        out.push('_');
    }
    out
}

/// A Rust (and C-like) string literal for any text: quotes, backslashes, control and
/// non-ASCII characters are escaped.
pub fn string_literal(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            ' '..='~' => out.push(c),
            _ => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_cannot_escape_or_inject() {
        assert_eq!(identifier("../../etc/passwd"), "______etc_passwd");
        assert_eq!(identifier("iiwa14"), "iiwa14");
        assert_eq!(identifier("KUKA LBR"), "kuka_lbr");
        assert_eq!(identifier("7dof"), "robot_7dof");
        assert_eq!(identifier(""), "robot_");
        assert_eq!(identifier("fn"), "fn_");
        assert_eq!(identifier("é\n}"), "___");
    }

    #[test]
    fn string_literals_cannot_end_early() {
        assert_eq!(string_literal("a\"b\\c"), r#""a\"b\\c""#);
        assert_eq!(string_literal("x\n*/ }"), r#""x\u{a}*/ }""#);
        assert_eq!(string_literal("ü"), r#""\u{fc}""#);
    }
}
