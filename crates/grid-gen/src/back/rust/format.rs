//! Formats the generated module with prettyplease one kernel at a time, with the same bytes
//! as formatting the whole file at once.
//!
//! Parsing a humanoid's whole module (16 MB of Rust) with syn took more than a gigabyte
//! and a quarter of the generator's time; a kernel at a time holds one kernel's syntax tree
//! per thread. Each kernel is formatted inside a module of its own, so that prettyplease
//! indents and breaks its lines exactly as it does inside the copy's module.

/// Top-level items, formatted. The error is syn's message where they do not parse.
pub(super) fn items(source: &str) -> Result<String, String> {
    syn::parse_file(source).map(|f| prettyplease::unparse(&f)).map_err(|e| e.to_string())
}

/// A copy's module header (doc comments, attributes, `pub mod name {`, `use super::*;`),
/// formatted as the start of the whole module: everything but its closing brace.
pub(super) fn module_start(header: &str) -> Result<String, String> {
    let text = items(&format!("{header}}}\n"))?;
    Ok(text.strip_suffix("}\n").unwrap_or(&text).to_string())
}

/// Items inside a copy's module (after its `use super::*;`), formatted as they are there.
pub(super) fn module_items(source: &str) -> Result<String, String> {
    let text = items(&format!("mod m {{\nuse super::*;\n{source}}}\n"))?;
    let body = text.strip_suffix("}\n").unwrap_or(&text);
    const USE: &str = "    use super::*;\n";
    Ok(body.find(USE).map_or(body, |at| &body[at + USE.len()..]).to_string())
}
