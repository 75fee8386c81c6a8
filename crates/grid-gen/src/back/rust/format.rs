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

/// Items inside a copy's module (after its `use super::*;`), formatted as they are there;
/// each behind `#[cfg(feature = "<feature>")]` where a feature is given.
pub(super) fn module_items(source: &str, feature: Option<&str>) -> Result<String, String> {
    let source = format!("mod m {{\nuse super::*;\n{source}}}\n");
    let mut file = syn::parse_file(&source).map_err(|e| e.to_string())?;
    if let Some(feature) = feature {
        let gate = syn::parse_str::<syn::ItemStruct>(&format!(
            "{}struct S;",
            super::super::feature_gate(feature)
        ))
        .map_err(|e| e.to_string())?
        .attrs;
        if let Some(syn::Item::Mod(m)) = file.items.first_mut() {
            for item in m.content.iter_mut().flat_map(|(_, items)| items.iter_mut().skip(1)) {
                let attrs = attributes(item)
                    .ok_or_else(|| format!("an item that feature {feature:?} cannot gate"))?;
                attrs.splice(0..0, gate.iter().cloned());
            }
        }
    }
    let text = prettyplease::unparse(&file);
    let body = text.strip_suffix("}\n").unwrap_or(&text);
    const USE: &str = "    use super::*;\n";
    Ok(body.find(USE).map_or(body, |at| &body[at + USE.len()..]).to_string())
}

/// Puts the fields of each struct of entries (`struct k_slots<T>(T, T, ...)`, thousands
/// of them, which prettyplease writes one per line) on lines of up to 100 columns.
pub(super) fn compact_slots(text: String) -> String {
    if !text.contains("<T>(\n") {
        return text;
    }
    let mut out = String::with_capacity(text.len());
    let mut lines = text.split_inclusive('\n').peekable();
    while let Some(line) = lines.next() {
        out.push_str(line);
        if !(line.trim_start().starts_with("struct ") && line.ends_with("<T>(\n")) {
            continue;
        }
        let mut fields = 0;
        let mut indent = "";
        while let Some(next) = lines.peek() {
            if next.trim() != "T," {
                break;
            }
            indent = &next[..next.len() - next.trim_start().len()];
            fields += 1;
            lines.next();
        }
        let per_line = ((100 - indent.len()) / 3).max(1);
        let mut left = fields;
        while left > 0 {
            let n = left.min(per_line);
            out.push_str(indent);
            out.push_str(&vec!["T,"; n].join(" "));
            out.push('\n');
            left -= n;
        }
    }
    out
}

/// An item's attributes (every kind of item the Rust backend writes has them).
fn attributes(item: &mut syn::Item) -> Option<&mut Vec<syn::Attribute>> {
    use syn::Item;
    Some(match item {
        Item::Const(i) => &mut i.attrs,
        Item::Enum(i) => &mut i.attrs,
        Item::Fn(i) => &mut i.attrs,
        Item::Impl(i) => &mut i.attrs,
        Item::Macro(i) => &mut i.attrs,
        Item::Mod(i) => &mut i.attrs,
        Item::Static(i) => &mut i.attrs,
        Item::Struct(i) => &mut i.attrs,
        Item::Type(i) => &mut i.attrs,
        Item::Use(i) => &mut i.attrs,
        _ => return None,
    })
}
