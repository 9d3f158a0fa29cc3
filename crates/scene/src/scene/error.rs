//! Errors of scene loading, and the helpers that locate a parse error in the scene text
//! (line:column from a byte offset, and the dotted key path at that offset).

use std::fmt;
use std::path::PathBuf;

use super::SceneFormat;

/// One problem found while validating a scene: the dotted key it concerns and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// Dotted key path, with array indices, e.g. `grid.cell_size` or `boundary.fixed[1].box`.
    pub key: String,
    /// What is wrong, including the offending value.
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

/// Why a scene could not be loaded. Every variant names the scene file, and every message is a
/// single line (the CLI prints it as the one-line reason of a non-zero exit).
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("{}: cannot read scene file: {source}", file.display())]
    Read {
        /// The scene file.
        file: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Syntax error, wrong type, unknown or missing key: the text does not deserialise into a
    /// [`super::Scene`].
    #[error("{}", parse_display(file, *format, *line, *column, key.as_deref(), message))]
    Parse {
        /// The scene file.
        file: PathBuf,
        /// The format it was read as.
        format: SceneFormat,
        /// 1-based line of the error, when known.
        line: Option<usize>,
        /// 1-based column (in characters) of the error, when known.
        column: Option<usize>,
        /// Dotted key path at the error (e.g. `grid.cell_size`), when it could be determined.
        key: Option<String>,
        /// The parser's message (one line), e.g. ``unknown field `cellsize`, expected one of …``.
        message: String,
    },
    /// The scene parsed but some values are out of range, inconsistent, or name missing files.
    /// All problems found are listed, not only the first.
    #[error("{}: invalid scene: {}", file.display(), join_problems(problems))]
    Invalid {
        /// The scene file.
        file: PathBuf,
        /// Every problem found (never empty).
        problems: Vec<Problem>,
    },
}

impl SceneError {
    /// The scene file the error is about.
    pub fn file(&self) -> &std::path::Path {
        match self {
            SceneError::Read { file, .. }
            | SceneError::Parse { file, .. }
            | SceneError::Invalid { file, .. } => file,
        }
    }

    /// The validation problems (empty for read and parse errors).
    pub fn problems(&self) -> &[Problem] {
        match self {
            SceneError::Invalid { problems, .. } => problems,
            _ => &[],
        }
    }
}

fn join_problems(problems: &[Problem]) -> String {
    problems
        .iter()
        .map(Problem::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

fn parse_display(
    file: &std::path::Path,
    format: SceneFormat,
    line: Option<usize>,
    column: Option<usize>,
    key: Option<&str>,
    message: &str,
) -> String {
    let mut s = file.display().to_string();
    if let Some(l) = line {
        s.push_str(&format!(":{l}"));
        if let Some(c) = column {
            s.push_str(&format!(":{c}"));
        }
    }
    s.push_str(&format!(": invalid {} scene", format.name()));
    if let Some(k) = key.filter(|k| !k.is_empty()) {
        s.push_str(&format!(" at `{k}`"));
    }
    s.push_str(": ");
    s.push_str(message);
    s
}

/// Collapse a possibly multi-line parser message onto one line.
pub(crate) fn one_line(message: &str) -> String {
    message.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// 1-based (line, column) of byte `offset` in `text`; the column counts characters.
pub(crate) fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = before.matches('\n').count() + 1;
    let column = text[line_start..offset].chars().count() + 1;
    (line, column)
}

/// Byte offset of a 1-based line and a 0-based byte column (serde_json's convention).
pub(crate) fn offset_of(text: &str, line: usize, byte_column: usize) -> usize {
    let mut start = 0;
    for _ in 1..line {
        match text[start..].find('\n') {
            Some(i) => start += i + 1,
            None => return text.len(),
        }
    }
    (start + byte_column).min(text.len())
}

/// Append `key` to a dotted `path`, quoting it when it is not a bare TOML key.
fn push_key(path: &str, key: &str) -> String {
    let bare = !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    let key = if bare {
        key.to_string()
    } else {
        format!("{key:?}")
    };
    if path.is_empty() {
        key
    } else {
        format!("{path}.{key}")
    }
}

/// If `message` is serde's "missing field `x`", the field name.
pub(crate) fn missing_field(message: &str) -> Option<&str> {
    let rest = message.strip_prefix("missing field `")?;
    rest.split('`').next()
}

/// The dotted key path of the innermost key or value of a TOML document whose span holds
/// `offset`. `None` when no key does (e.g. the error is about the whole document).
pub(crate) fn toml_key_at(text: &str, offset: usize) -> Option<String> {
    let mut best: Option<(usize, usize, String)> = None;
    toml_visit(text, &mut |span, path, depth, _is_key| {
        let inside = span.start <= offset && (offset < span.end || span.start == span.end);
        if !inside {
            return;
        }
        let len = span.end - span.start;
        let better = match &best {
            None => true,
            Some((l, d, _)) => len < *l || (len == *l && depth > *d),
        };
        if better {
            best = Some((len, depth, path.to_string()));
        }
    });
    best.map(|b| b.2)
}

/// The dotted key path of the TOML value whose span is exactly `span` (how toml locates a
/// "missing field" error: the span of the table lacking it). `None` when there is none, e.g.
/// for the document itself.
pub(crate) fn toml_value_with_span(text: &str, span: std::ops::Range<usize>) -> Option<String> {
    let mut found = None;
    toml_visit(text, &mut |s, path, _, is_key| {
        // Pre-order walk: a later match with the same span is nested deeper (an array of
        // tables and its only element share a span); keep the deepest.
        if s == span && !is_key {
            found = Some(path.to_string());
        }
    });
    found
}

/// Callback of [`toml_visit`]: (span, dotted path, depth, is a key span).
type Visit<'a> = dyn FnMut(std::ops::Range<usize>, &str, usize, bool) + 'a;

/// Visit the span of every key and value of a TOML document (recovering from syntax errors),
/// with its dotted path, nesting depth, and whether it is the span of a key (else of a value).
fn toml_visit(text: &str, f: &mut Visit<'_>) {
    use toml::de::{DeTable, DeValue};
    fn walk_value(v: &toml::Spanned<DeValue<'_>>, path: &str, depth: usize, f: &mut Visit<'_>) {
        f(v.span(), path, depth, false);
        match v.get_ref() {
            DeValue::Table(t) => walk_table(t, path, depth + 1, f),
            DeValue::Array(a) => {
                for (i, item) in a.iter().enumerate() {
                    walk_value(item, &format!("{path}[{i}]"), depth + 1, f);
                }
            }
            _ => {}
        }
    }
    fn walk_table(t: &DeTable<'_>, path: &str, depth: usize, f: &mut Visit<'_>) {
        for (k, v) in t.iter() {
            let p = push_key(path, k.get_ref());
            f(k.span(), &p, depth, true);
            walk_value(v, &p, depth, f);
        }
    }
    let (doc, _errors) = DeTable::parse_recoverable(text);
    walk_table(doc.get_ref(), "", 0, f);
}

/// One level of nesting in a JSON document, as seen by [`json_frames_at`].
#[derive(Debug)]
enum JsonFrame {
    Object {
        key: Option<String>,
        expect_key: bool,
    },
    Array {
        index: usize,
    },
}

/// The nesting of a JSON document just before byte `offset`.
fn json_frames_at(text: &str, offset: usize) -> Vec<JsonFrame> {
    let bytes = text.as_bytes();
    let end = offset.min(bytes.len());
    let mut frames: Vec<JsonFrame> = Vec::new();
    let mut i = 0;
    while i < end {
        match bytes[i] {
            b'"' => {
                let start = i + 1;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    j += if bytes[j] == b'\\' { 2 } else { 1 };
                }
                let j = j.min(bytes.len());
                if let Some(JsonFrame::Object { key, expect_key }) = frames.last_mut() {
                    if *expect_key {
                        let raw = &text[start..j];
                        *key = Some(
                            serde_json::from_str::<String>(&format!("\"{raw}\""))
                                .unwrap_or_else(|_| raw.to_string()),
                        );
                        *expect_key = false;
                    }
                }
                i = j + 1;
                continue;
            }
            b'{' => frames.push(JsonFrame::Object {
                key: None,
                expect_key: true,
            }),
            b'[' => frames.push(JsonFrame::Array { index: 0 }),
            b'}' | b']' => {
                frames.pop();
            }
            b',' => match frames.last_mut() {
                Some(JsonFrame::Object { key, expect_key }) => {
                    *key = None;
                    *expect_key = true;
                }
                Some(JsonFrame::Array { index }) => *index += 1,
                None => {}
            },
            _ => {}
        }
        i += 1;
    }
    frames
}

/// The dotted key path in a JSON document at byte `offset`; with `parent`, the path of the
/// innermost enclosing object (used for "missing field" errors, which point at its end).
pub(crate) fn json_key_at(text: &str, offset: usize, parent: bool) -> String {
    let frames = json_frames_at(text, offset);
    let mut path = String::new();
    let n = frames.len();
    for (depth, f) in frames.iter().enumerate() {
        match f {
            JsonFrame::Object { key: Some(k), .. } if !(parent && depth + 1 == n) => {
                path = push_key(&path, k);
            }
            JsonFrame::Object { .. } => break,
            JsonFrame::Array { index } => path.push_str(&format!("[{index}]")),
        }
    }
    path
}
