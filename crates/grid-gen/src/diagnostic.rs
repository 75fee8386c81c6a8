//! Located findings about an input file: what is wrong, where, and how to fix it.
//!
//! The library only builds these; rendering them (with colours, source excerpts) is the
//! caller's choice. [`Diagnostic::render_plain`] gives a dependency-free one-block form
//! for `build.rs` users, and the CLI renders them with codespan-reporting.

use std::fmt;
use std::ops::Range;

/// How serious a finding is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Severity {
    /// The input cannot be used.
    Error,
    /// The input is usable but probably not what was meant (`--strict` makes it an error).
    Warning,
}

/// One finding, pointing at a byte range of the source text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    pub severity: Severity,
    /// Short, lower-case, no trailing period.
    pub message: String,
    /// Byte range of the offending element or attribute; `None` when the problem has no
    /// single place (an empty file, a robot without links).
    pub span: Option<Range<usize>>,
    /// What the span shows.
    pub label: String,
    /// How to fix it.
    pub help: Option<String>,
}

impl Diagnostic {
    pub fn error(
        message: impl Into<String>,
        span: Option<Range<usize>>,
        label: impl Into<String>,
    ) -> Self {
        Diagnostic {
            severity: Severity::Error,
            message: message.into(),
            span,
            label: label.into(),
            help: None,
        }
    }

    pub fn warning(
        message: impl Into<String>,
        span: Option<Range<usize>>,
        label: impl Into<String>,
    ) -> Self {
        Diagnostic {
            severity: Severity::Warning,
            message: message.into(),
            span,
            label: label.into(),
            help: None,
        }
    }

    pub fn with_help(mut self, help: impl Into<String>) -> Self {
        self.help = Some(help.into());
        self
    }

    /// Renders `path:line:col: error: message`, the offending source line, and the help,
    /// without colours or extra dependencies.
    pub fn render_plain(&self, path: &str, source: &str) -> String {
        let kind = match self.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
        };
        let mut out = match &self.span {
            Some(span) => {
                let (line, col) = line_col(source, span.start);
                format!("{path}:{line}:{col}: {kind}: {}\n", self.message)
            }
            None => format!("{path}: {kind}: {}\n", self.message),
        };
        if let Some(span) = &self.span {
            let (line, _) = line_col(source, span.start);
            if let Some(text) = source.lines().nth(line - 1) {
                out.push_str(&format!("  {line} | {}\n", text.trim_end()));
            }
        }
        if !self.label.is_empty() {
            out.push_str(&format!("  = {}\n", self.label));
        }
        if let Some(help) = &self.help {
            out.push_str(&format!("  = help: {help}\n"));
        }
        out
    }
}

/// 1-based line and column (in characters) of a byte offset.
pub fn line_col(source: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(source.len());
    let before = &source[..floor_char_boundary(source, offset)];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

fn floor_char_boundary(s: &str, mut i: usize) -> usize {
    while i > 0 && !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// A robot description that could not be used, with every error found (and the warnings
/// seen before the errors).
#[derive(Clone, Debug, thiserror::Error)]
pub struct LoadError {
    /// Display name of the input (usually its path).
    pub path: String,
    /// The input text, so that callers can render excerpts.
    pub source_text: String,
    pub diagnostics: Vec<Diagnostic>,
}

impl LoadError {
    /// All diagnostics rendered with [`Diagnostic::render_plain`].
    pub fn render_plain(&self) -> String {
        self.diagnostics
            .iter()
            .map(|d| d.render_plain(&self.path, &self.source_text))
            .collect::<Vec<_>>()
            .join("")
    }
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let errors = self.diagnostics.iter().filter(|d| d.severity == Severity::Error).count();
        write!(f, "{}: {} error(s) in the robot description", self.path, errors)?;
        if let Some(first) = self.diagnostics.iter().find(|d| d.severity == Severity::Error) {
            write!(f, "; first: {}", first.message)?;
        }
        Ok(())
    }
}
