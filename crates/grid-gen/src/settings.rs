//! The settings a caller may give beside a scene file, each declared once with its name in
//! every place it can come from (the scene's TOML key, the CLI flag, the `Builder` method,
//! the Python keyword), and where a loaded scene's value came from, so that an error names
//! the true source: `--dt`, `scene `s.toml` line 7: [step] dt`, `Builder::dt`,
//! `load(dt=...)`.
//!
//! The table is the declaration, and each surface is held to it by a test rather than
//! generated from it: the CLI's flags by clap's own description of the command
//! (`grid-gen-cli`'s `every_setting_has_its_flag`), the `Builder` methods by their source
//! (`settings_name_real_builder_methods`), the Python keywords by `load`'s signature
//! (`test_every_setting_is_a_load_keyword`) and the TOML keys by finding each in a scene
//! that sets them all (`every_setting_has_a_line`). Rust has no reflection, and a macro that
//! wrote the methods and flags would hide their documentation from readers and rustdoc.

/// One setting, by its names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Setting {
    /// The Python keyword, and this table's key.
    pub key: &'static str,
    /// Where a scene file holds it, as an error names it.
    pub toml: &'static str,
    /// The same as a path of TOML keys (a table's name, then the key in it).
    pub path: &'static [&'static str],
    pub flag: &'static str,
    pub builder: &'static str,
}

/// Every setting [`crate::SceneOverrides`] carries.
pub const SETTINGS: [Setting; 11] = [
    Setting {
        key: "gravity",
        toml: "gravity",
        path: &["gravity"],
        flag: "--gravity",
        builder: "Builder::gravity",
    },
    Setting {
        key: "floating_base",
        toml: "floating_base",
        path: &["floating_base"],
        flag: "--floating-base",
        builder: "Builder::floating_base",
    },
    Setting {
        key: "frames",
        toml: "[frames]",
        path: &["frames"],
        flag: "--frames",
        builder: "Builder::frames",
    },
    Setting {
        key: "step",
        toml: "[step]",
        path: &["step"],
        flag: "--step",
        builder: "Builder::step",
    },
    Setting {
        key: "dt",
        toml: "[step] dt",
        path: &["step", "dt"],
        flag: "--dt",
        builder: "Builder::dt",
    },
    Setting {
        key: "actuated",
        toml: "[actuation] joints",
        path: &["actuation", "joints"],
        flag: "--actuated",
        builder: "Builder::actuated",
    },
    Setting {
        key: "external_forces",
        toml: "[external_forces] joints",
        path: &["external_forces", "joints"],
        flag: "--fext",
        builder: "Builder::external_forces",
    },
    Setting {
        key: "contacts",
        toml: "[[contact]]",
        path: &["contact"],
        flag: "--contact",
        builder: "Builder::contacts",
    },
    Setting {
        key: "contact_mask",
        toml: "contact_mask",
        path: &["contact_mask"],
        flag: "--contact-mask",
        builder: "Builder::contact_mask",
    },
    Setting {
        key: "baumgarte",
        toml: "baumgarte",
        path: &["baumgarte"],
        flag: "--baumgarte",
        builder: "Builder::baumgarte",
    },
    Setting {
        key: "round_angles",
        toml: "round_angles",
        path: &["round_angles"],
        flag: "--round-angles",
        builder: "Builder::round_angles",
    },
];

/// Who gave a [`crate::SceneOverrides`]' values.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Source {
    /// `Builder` methods (and a `Config` built by hand).
    #[default]
    Builder,
    /// The command line's flags.
    Flags,
    /// A function's keywords, by the function's name (`load` for the Python package).
    Keywords(String),
}

impl Source {
    /// How an error names `key` given by this source.
    pub fn name(&self, key: &str) -> String {
        let s = setting(key);
        match self {
            Source::Builder => s.builder.to_string(),
            Source::Flags => s.flag.to_string(),
            Source::Keywords(caller) => format!("{caller}({}=...)", s.key),
        }
    }
}

/// The setting named `key`.
///
/// # Panics
/// When no setting is named so: the keys are this module's constants.
pub fn setting(key: &str) -> &'static Setting {
    SETTINGS.iter().find(|s| s.key == key).unwrap_or_else(|| panic!("no setting `{key}`"))
}

/// How an error names setting `key` of a scene read from `path` (empty: no file), where
/// `given` says who replaced the file's value, if anyone did, and `line` where the file
/// sets it.
pub fn whence(key: &str, path: &str, given: Option<&Source>, line: Option<usize>) -> String {
    match (given, line) {
        (Some(source), _) => source.name(key),
        (None, _) if path.is_empty() => Source::Flags.name(key),
        (None, Some(line)) => format!("scene `{path}` line {line}: {}", setting(key).toml),
        (None, None) => format!("scene `{path}`: {}", setting(key).toml),
    }
}

/// The line (from 1) of each setting a scene's text sets: its key's line, or its table's
/// header for a table (the first `[[contact]]` for the contacts). Settings the text does
/// not set, and any text TOML cannot parse, have none.
pub fn lines(text: &str) -> std::collections::BTreeMap<&'static str, usize> {
    let mut out = std::collections::BTreeMap::new();
    let Ok(doc) = toml_edit::ImDocument::parse(text) else {
        return out;
    };
    let line = |at: usize| 1 + text[..at.min(text.len())].matches('\n').count();
    for s in &SETTINGS {
        let root = doc.as_table();
        let span = match s.path {
            [key] => root.key(key).and_then(|k| k.span()).or_else(|| {
                root.get(key).and_then(|item| match item {
                    toml_edit::Item::ArrayOfTables(a) => a.get(0).and_then(|t| t.span()),
                    item => item.span(),
                })
            }),
            [table, key] => root
                .get(table)
                .and_then(|t| t.as_table_like())
                .and_then(|t| t.get_key_value(key))
                .and_then(|(k, v)| k.span().or_else(|| v.span())),
            _ => None,
        };
        if let Some(span) = span {
            out.insert(s.key, line(span.start));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every setting's TOML path finds its line in a scene that sets them all: the paths are
    /// the scene format's keys.
    #[test]
    fn every_setting_has_a_line() {
        let text = "gravity = [0, 0, -9.81]\nfloating_base = true\ncontact_mask = true\n\
                    baumgarte = true\nround_angles = 1e-6\n\n[frames]\nlinks = [\"a\"]\n\n\
                    [step]\nscheme = \"rk4\"\ndt = 0.01\n\n[actuation]\njoints = [\"j\"]\n\n\
                    [external_forces]\njoints = [\"j\"]\n\n[[contact]]\nframe = \"a\"\n\
                    type = \"point\"\n";
        let found = lines(text);
        for s in &SETTINGS {
            let line = found.get(s.key).unwrap_or_else(|| panic!("no line for `{}`", s.key));
            let at = text.lines().nth(line - 1).unwrap();
            let last = s.path.last().unwrap();
            assert!(at.contains(last), "`{}` at line {line}: {at}", s.key);
        }
        assert_eq!(found["dt"], 12);
        assert_eq!(found["step"], 10);
        assert_eq!(found["contacts"], 20);
    }

    /// Each `builder` names a method of [`crate::Builder`] (its source declares it).
    #[test]
    fn settings_name_real_builder_methods() {
        let source = include_str!("builder.rs");
        for s in &SETTINGS {
            let method = s.builder.strip_prefix("Builder::").expect("Builder::name");
            let declared = source.contains(&format!("pub fn {method}("))
                || source.contains(&format!("pub fn {method}<"));
            assert!(declared, "no Builder::{method}");
        }
    }
}
