//! The shared namer: names from a URDF made safe for every target. File stems and
//! identifiers cannot escape the output folder or break the code in any target's
//! language, string literals cannot end early, and comment text cannot end a comment.

/// A lower-case identifier made of `[a-z0-9_]`, never empty, never starting with a digit,
/// never a reserved word of any target (Rust, WGSL, Verilog). Anything else in the name
/// becomes `_`. The same identifier is the file stem of every target's file.
pub fn identifier(name: &str) -> String {
    let mut out: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' })
        .collect();
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, "robot_");
    }
    if is_reserved(&out) {
        out.push('_');
    }
    out
}

/// Rust keywords (2024 edition, strict and reserved ones that are lower-case).
const RUST: &[&str] = &[
    "abstract", "as", "async", "await", "become", "box", "break", "const", "continue", "crate",
    "do", "dyn", "else", "enum", "extern", "false", "final", "fn", "for", "gen", "if", "impl",
    "in", "let", "loop", "macro", "match", "mod", "move", "mut", "override", "priv", "pub", "ref",
    "return", "self", "static", "struct", "super", "trait", "true", "try", "type", "typeof",
    "unsafe", "unsized", "use", "virtual", "where", "while", "yield", "_",
];

/// WGSL keywords and the reserved words that are lower-case identifiers (WGSL spec, 15.2
/// and 15.3), plus the predeclared type names our shaders use.
const WGSL: &[&str] = &[
    "alias",
    "break",
    "case",
    "const",
    "const_assert",
    "continue",
    "continuing",
    "default",
    "diagnostic",
    "discard",
    "else",
    "enable",
    "false",
    "fn",
    "for",
    "if",
    "let",
    "loop",
    "override",
    "requires",
    "return",
    "struct",
    "switch",
    "true",
    "var",
    "while",
    "abstract",
    "active",
    "alignas",
    "alignof",
    "as",
    "asm",
    "asm_fragment",
    "async",
    "attribute",
    "auto",
    "await",
    "become",
    "cast",
    "catch",
    "class",
    "co_await",
    "co_return",
    "co_yield",
    "coherent",
    "column_major",
    "common",
    "compile",
    "compile_fragment",
    "concept",
    "const_cast",
    "consteval",
    "constexpr",
    "constinit",
    "crate",
    "debugger",
    "decltype",
    "delete",
    "demote",
    "demote_to_helper",
    "do",
    "dynamic_cast",
    "enum",
    "explicit",
    "export",
    "extends",
    "extern",
    "external",
    "fallthrough",
    "filter",
    "final",
    "finally",
    "friend",
    "from",
    "fxgroup",
    "get",
    "goto",
    "groupshared",
    "highp",
    "impl",
    "implements",
    "import",
    "inline",
    "instanceof",
    "interface",
    "layout",
    "lowp",
    "macro",
    "macro_rules",
    "match",
    "mediump",
    "meta",
    "mod",
    "module",
    "move",
    "mut",
    "mutable",
    "namespace",
    "new",
    "nil",
    "noexcept",
    "noinline",
    "nointerpolation",
    "non_coherent",
    "noncoherent",
    "noperspective",
    "null",
    "nullptr",
    "of",
    "operator",
    "package",
    "packoffset",
    "partition",
    "pass",
    "patch",
    "pixelfragment",
    "precise",
    "precision",
    "premerge",
    "priv",
    "protected",
    "pub",
    "public",
    "readonly",
    "ref",
    "regardless",
    "register",
    "reinterpret_cast",
    "require",
    "resource",
    "restrict",
    "self",
    "set",
    "shared",
    "sizeof",
    "smooth",
    "snorm",
    "static",
    "static_assert",
    "static_cast",
    "std",
    "subroutine",
    "super",
    "target",
    "template",
    "this",
    "thread_local",
    "throw",
    "trait",
    "try",
    "type",
    "typedef",
    "typeid",
    "typename",
    "typeof",
    "union",
    "unless",
    "unorm",
    "unsafe",
    "unsized",
    "use",
    "using",
    "varying",
    "virtual",
    "volatile",
    "wgsl",
    "where",
    "with",
    "writeonly",
    "yield",
    "f32",
    "f64",
    "i32",
    "u32",
    "bool",
    "array",
    "vec2",
    "vec3",
    "vec4",
    "ptr",
    "sampler",
    "atomic",
];

/// Verilog-2005 keywords (IEEE 1364-2005, annex B).
const VERILOG: &[&str] = &[
    "always",
    "and",
    "assign",
    "automatic",
    "begin",
    "buf",
    "bufif0",
    "bufif1",
    "case",
    "casex",
    "casez",
    "cell",
    "cmos",
    "config",
    "deassign",
    "default",
    "defparam",
    "design",
    "disable",
    "edge",
    "else",
    "end",
    "endcase",
    "endconfig",
    "endfunction",
    "endgenerate",
    "endmodule",
    "endprimitive",
    "endspecify",
    "endtable",
    "endtask",
    "event",
    "for",
    "force",
    "forever",
    "fork",
    "function",
    "generate",
    "genvar",
    "highz0",
    "highz1",
    "if",
    "ifnone",
    "incdir",
    "include",
    "initial",
    "inout",
    "input",
    "instance",
    "integer",
    "join",
    "large",
    "liblist",
    "library",
    "localparam",
    "macromodule",
    "medium",
    "module",
    "nand",
    "negedge",
    "nmos",
    "nor",
    "noshowcancelled",
    "not",
    "notif0",
    "notif1",
    "or",
    "output",
    "parameter",
    "pmos",
    "posedge",
    "primitive",
    "pull0",
    "pull1",
    "pulldown",
    "pullup",
    "pulsestyle_onevent",
    "pulsestyle_ondetect",
    "rcmos",
    "real",
    "realtime",
    "reg",
    "release",
    "repeat",
    "rnmos",
    "rpmos",
    "rtran",
    "rtranif0",
    "rtranif1",
    "scalared",
    "showcancelled",
    "signed",
    "small",
    "specify",
    "specparam",
    "strong0",
    "strong1",
    "supply0",
    "supply1",
    "table",
    "task",
    "time",
    "tran",
    "tranif0",
    "tranif1",
    "tri",
    "tri0",
    "tri1",
    "triand",
    "trior",
    "trireg",
    "unsigned",
    "use",
    "uwire",
    "vectored",
    "wait",
    "wand",
    "weak0",
    "weak1",
    "while",
    "wire",
    "wor",
    "xnor",
    "xor",
];

/// Whether a lower-case word is reserved in any target's language.
pub fn is_reserved(word: &str) -> bool {
    RUST.contains(&word) || WGSL.contains(&word) || VERILOG.contains(&word)
}

/// Text for a line comment in any target: printable ASCII only (everything else, line
/// breaks included, escaped as `\u{..}`), so a name cannot end the comment or the line.
pub fn comment_text(text: &str) -> String {
    let quoted = string_literal(text);
    // `*/` cannot close a block comment either.
    quoted[1..quoted.len() - 1].replace("*/", "*\\/")
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
        assert_eq!(identifier("var"), "var_");
        assert_eq!(identifier("module"), "module_");
        assert_eq!(identifier("é\n}"), "___");
    }

    #[test]
    fn comments_cannot_be_ended_by_a_name() {
        assert_eq!(comment_text("a\nb */ c"), "a\\u{a}b *\\/ c");
        assert!(!comment_text("x\r\n\u{2028}y").contains(['\n', '\r', '\u{2028}']));
    }

    #[test]
    fn string_literals_cannot_end_early() {
        assert_eq!(string_literal("a\"b\\c"), r#""a\"b\\c""#);
        assert_eq!(string_literal("x\n*/ }"), r#""x\u{a}*/ }""#);
        assert_eq!(string_literal("ü"), r#""\u{fc}""#);
    }
}
