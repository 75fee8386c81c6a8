//! The settings a caller may give beside a scene file, each declared once with its name in
//! every place it can come from (the scene's TOML key, the CLI flag, the `Builder` method,
//! the Python keyword), and where a loaded scene's value came from, so that an error names
//! the true source: `--dt`, `scene `s.toml`: [step] dt`, `Builder::dt`, `load(dt=...)`.

/// One setting, by its names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Setting {
    /// The Python keyword, and this table's key.
    pub key: &'static str,
    /// Where a scene file holds it.
    pub toml: &'static str,
    pub flag: &'static str,
    pub builder: &'static str,
}

/// Every setting [`crate::SceneOverrides`] carries.
pub const SETTINGS: [Setting; 11] = [
    Setting { key: "gravity", toml: "gravity", flag: "--gravity", builder: "Builder::gravity" },
    Setting {
        key: "floating_base",
        toml: "floating_base",
        flag: "--floating-base",
        builder: "Builder::floating_base",
    },
    Setting { key: "frames", toml: "[frames]", flag: "--frames", builder: "Builder::frames" },
    Setting { key: "step", toml: "[step]", flag: "--step", builder: "Builder::step" },
    Setting { key: "dt", toml: "[step] dt", flag: "--dt", builder: "Builder::dt" },
    Setting {
        key: "actuated",
        toml: "[actuation] joints",
        flag: "--actuated",
        builder: "Builder::actuated",
    },
    Setting {
        key: "external_forces",
        toml: "[external_forces] joints",
        flag: "--fext",
        builder: "Builder::external_forces",
    },
    Setting {
        key: "contacts",
        toml: "[[contact]]",
        flag: "--contact",
        builder: "Builder::contacts",
    },
    Setting {
        key: "contact_mask",
        toml: "contact_mask",
        flag: "--contact-mask",
        builder: "Builder::contact_mask",
    },
    Setting {
        key: "baumgarte",
        toml: "baumgarte",
        flag: "--baumgarte",
        builder: "Builder::baumgarte",
    },
    Setting {
        key: "round_angles",
        toml: "round_angles",
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
/// `given` says who replaced the file's value, if anyone did.
pub fn whence(key: &str, path: &str, given: Option<&Source>) -> String {
    match given {
        Some(source) => source.name(key),
        None if path.is_empty() => Source::Flags.name(key),
        None => format!("scene `{path}`: {}", setting(key).toml),
    }
}
