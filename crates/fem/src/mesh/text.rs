//! Line-oriented text parsing shared by the text readers: reading a file, numbered non-blank
//! lines with optional `#` comments, and whitespace- (or comma-) separated tokens parsed into
//! numbers with errors that name the file, the line and the offending token.

use std::borrow::Cow;
use std::fs;
use std::path::Path;

use nalgebra::Point3;

use super::error::MeshError;

/// Reads the whole file.
pub(crate) fn read_bytes(path: &Path) -> Result<Vec<u8>, MeshError> {
    fs::read(path).map_err(|e| MeshError::io(path, e))
}

/// The UTF-8 byte order mark some editors put at the start of text files.
pub(crate) const BOM: &[u8] = b"\xef\xbb\xbf";

/// Decodes text leniently: a leading byte order mark is dropped, and invalid UTF-8 becomes U+FFFD,
/// which the token parser then reports with its line number rather than failing the whole file up
/// front.
pub(crate) fn decode(bytes: &[u8]) -> Cow<'_, str> {
    String::from_utf8_lossy(bytes.strip_prefix(BOM).unwrap_or(bytes))
}

/// Quotes `s` for an error message: shortened to at most 40 characters, control characters
/// escaped.
pub(crate) fn quote(s: &str) -> String {
    const MAX: usize = 40;
    let mut out = String::from("'");
    for (i, c) in s.chars().enumerate() {
        if i == MAX {
            out.push('…');
            break;
        }
        if c.is_control() {
            out.extend(c.escape_debug());
        } else {
            out.push(c);
        }
    }
    out + "'"
}

/// Iterator over the non-blank lines of a text, with 1-based line numbers and comments removed.
pub(crate) struct Lines<'a> {
    path: &'a Path,
    inner: std::iter::Enumerate<std::str::Lines<'a>>,
    first_line: usize,
    comment: Option<char>,
}

impl<'a> Lines<'a> {
    /// Lines of `text`, the whole of `path`, with everything from `comment` to the end of a line
    /// removed.
    pub(crate) fn new(path: &'a Path, text: &'a str, comment: Option<char>) -> Self {
        Self::starting_at(path, text, 1, comment)
    }

    /// Lines of `text`, a part of `path` whose first line is line `first_line` of the file.
    pub(crate) fn starting_at(
        path: &'a Path,
        text: &'a str,
        first_line: usize,
        comment: Option<char>,
    ) -> Self {
        Self {
            path,
            inner: text.lines().enumerate(),
            first_line,
            comment,
        }
    }

    /// The file the lines belong to.
    pub(crate) fn path(&self) -> &'a Path {
        self.path
    }

    /// The next non-blank line, or an error saying that `what` was expected before the end of
    /// the file.
    pub(crate) fn expect(&mut self, what: &str) -> Result<Line<'a>, MeshError> {
        self.next().ok_or_else(|| {
            MeshError::malformed(
                self.path,
                format!("unexpected end of file: expected {what} (truncated file?)"),
            )
        })
    }
}

impl<'a> Iterator for Lines<'a> {
    type Item = Line<'a>;

    fn next(&mut self) -> Option<Line<'a>> {
        for (i, raw) in self.inner.by_ref() {
            let text = match self.comment.and_then(|c| raw.find(c)) {
                Some(cut) => &raw[..cut],
                None => raw,
            };
            let text = text.trim();
            if !text.is_empty() {
                return Some(Line {
                    path: self.path,
                    no: self.first_line + i,
                    text,
                });
            }
        }
        None
    }
}

/// One non-blank line of a text file, trimmed and without its comment.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Line<'a> {
    /// The file the line belongs to.
    pub path: &'a Path,
    /// 1-based line number.
    pub no: usize,
    /// Content of the line.
    pub text: &'a str,
}

impl<'a> Line<'a> {
    /// A parse error at this line.
    pub(crate) fn err(&self, message: impl Into<String>) -> MeshError {
        MeshError::parse(self.path, self.no, message)
    }

    /// The whitespace-separated tokens of the line.
    pub(crate) fn tokens(&self) -> Tokens<'a> {
        self.tokens_split_by(char::is_whitespace)
    }

    /// The tokens of the line, separated by runs of characters matching `sep`.
    pub(crate) fn tokens_split_by(&self, sep: fn(char) -> bool) -> Tokens<'a> {
        Tokens {
            line: *self,
            rest: self.text,
            sep,
        }
    }
}

/// Tokens of one line, with parsers that report errors at that line.
pub(crate) struct Tokens<'a> {
    line: Line<'a>,
    rest: &'a str,
    sep: fn(char) -> bool,
}

impl<'a> Iterator for Tokens<'a> {
    type Item = &'a str;

    fn next(&mut self) -> Option<&'a str> {
        let rest = self.rest.trim_start_matches(self.sep);
        if rest.is_empty() {
            self.rest = rest;
            return None;
        }
        let end = rest.find(self.sep).unwrap_or(rest.len());
        self.rest = &rest[end..];
        Some(&rest[..end])
    }
}

impl<'a> Tokens<'a> {
    /// The line these tokens come from.
    pub(crate) fn line(&self) -> Line<'a> {
        self.line
    }

    /// A parse error at this line.
    pub(crate) fn err(&self, message: impl Into<String>) -> MeshError {
        self.line.err(message)
    }

    /// The next token, or an error saying that `what` was expected.
    pub(crate) fn expect(&mut self, what: &str) -> Result<&'a str, MeshError> {
        self.next()
            .ok_or_else(|| self.err(format!("expected {what}, found end of line")))
    }

    /// The next token as a finite number.
    pub(crate) fn finite(&mut self, what: &str) -> Result<f64, MeshError> {
        let token = self.expect(what)?;
        let value = self.number(token, what)?;
        if value.is_finite() {
            Ok(value)
        } else {
            Err(self.err(format!("{what} {} is not a finite number", quote(token))))
        }
    }

    /// The next token as a number (NaN and infinities allowed).
    pub(crate) fn float(&mut self, what: &str) -> Result<f64, MeshError> {
        let token = self.expect(what)?;
        self.number(token, what)
    }

    fn number(&self, token: &str, what: &str) -> Result<f64, MeshError> {
        token.parse().map_err(|_| {
            self.err(format!(
                "expected {what} (a number), found {}",
                quote(token)
            ))
        })
    }

    /// The next token as an integer.
    pub(crate) fn int(&mut self, what: &str) -> Result<i64, MeshError> {
        let token = self.expect(what)?;
        token.parse().map_err(|_| {
            self.err(format!(
                "expected {what} (an integer), found {}",
                quote(token)
            ))
        })
    }

    /// The next token as a non-negative integer (a count or an index).
    pub(crate) fn uint(&mut self, what: &str) -> Result<usize, MeshError> {
        let token = self.expect(what)?;
        token.parse().map_err(|_| {
            self.err(format!(
                "expected {what} (a non-negative integer), found {}",
                quote(token)
            ))
        })
    }

    /// The next three tokens as a point with finite coordinates.
    pub(crate) fn point(&mut self) -> Result<Point3<f64>, MeshError> {
        Ok(Point3::new(
            self.finite("x coordinate")?,
            self.finite("y coordinate")?,
            self.finite("z coordinate")?,
        ))
    }

    /// Fails if any token is left on the line.
    pub(crate) fn end(&mut self) -> Result<(), MeshError> {
        match self.next() {
            None => Ok(()),
            Some(extra) => Err(self.err(format!("unexpected extra value {}", quote(extra)))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_skip_blanks_and_comments_and_count_from_one() {
        let p = Path::new("a.txt");
        let text = "# head\n\n  v 1 2 3 # tail\r\n\t\nf 1 2 3";
        let lines: Vec<_> = Lines::new(p, text, Some('#'))
            .map(|l| (l.no, l.text))
            .collect();
        assert_eq!(lines, vec![(3, "v 1 2 3"), (5, "f 1 2 3")]);
        let lines: Vec<_> = Lines::starting_at(p, "x\ny", 10, None)
            .map(|l| l.no)
            .collect();
        assert_eq!(lines, vec![10, 11]);
    }

    #[test]
    fn tokens_parse_numbers_and_report_line() {
        let p = Path::new("pts.csv");
        let mut lines = Lines::new(p, "\n1.5,\t-2 ,3e2\nx nan 1\n", None);
        let line = lines.next().unwrap();
        let mut t = line.tokens_split_by(|c| c.is_whitespace() || c == ',');
        assert_eq!(t.point().unwrap(), Point3::new(1.5, -2.0, 300.0));
        assert!(t.end().is_ok());
        let line = lines.next().unwrap();
        let mut t = line.tokens();
        let e = t.finite("x coordinate").unwrap_err().to_string();
        assert_eq!(e, "pts.csv:3: expected x coordinate (a number), found 'x'");
        let e = t.finite("y coordinate").unwrap_err().to_string();
        assert_eq!(e, "pts.csv:3: y coordinate 'nan' is not a finite number");
        assert_eq!(t.int("n").unwrap(), 1);
        let e = t.uint("n").unwrap_err().to_string();
        assert_eq!(e, "pts.csv:3: expected n, found end of line");
        assert!(lines
            .expect("more")
            .unwrap_err()
            .to_string()
            .contains("pts.csv"));
    }

    #[test]
    fn quote_shortens_long_garbage() {
        assert_eq!(quote("abc"), "'abc'");
        let long = "é".repeat(100);
        let q = quote(&long);
        assert_eq!(q.chars().count(), 43);
        assert_eq!(quote("a\0b\tc"), "'a\\0b\\tc'");
    }
}
