//! Where a problem in a scene file is: the TOML parser's spans give the line, and
//! `serde_path_to_error` gives the dotted key of a deserialisation error, so every message
//! reads `file:line: key: what is wrong`. A check after deserialisation names its key as a
//! dotted string (`species[1].params.height`), which is looked up in the parsed document for
//! its line and the value as written.

use std::ops::Range;

use serde::de::DeserializeOwned;
use toml::Spanned;
use toml::de::{DeTable, DeValue};

use super::SceneError;
use crate::model::FieldError;

/// Longest message passed on from the deserialiser (a value it quotes can be long).
const MAX_MESSAGE_CHARS: usize = 200;

/// A parsed scene text, kept to locate errors in it.
pub(super) struct Document<'a> {
    text: &'a str,
    origin: &'a str,
    root: Spanned<DeTable<'a>>,
}

impl<'a> Document<'a> {
    /// Parses `text` as TOML; a syntax error names the line. `origin` is the file name
    /// used in messages.
    pub(super) fn parse(text: &'a str, origin: &'a str) -> Result<Self, SceneError> {
        let root = DeTable::parse(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            let mut message = e.message().trim().to_owned();
            if message == "duplicate key"
                && let Some(k) = text.get(span.clone())
            {
                message = format!("duplicate key `{}`", k.trim());
            }
            SceneError::Syntax {
                origin: origin.to_owned(),
                line: line_of(text, span.start),
                message,
            }
        })?;
        Ok(Document { text, origin, root })
    }

    /// Deserialises the document; an error names the key (its dotted path) and the line.
    pub(super) fn deserialize<T: DeserializeOwned>(&self) -> Result<T, SceneError> {
        let de = toml::Deserializer::from(self.root.clone());
        serde_path_to_error::deserialize(de).map_err(|e| self.serde_error(&e))
    }

    fn invalid(&self, line: usize, key: String, message: String) -> SceneError {
        SceneError::Invalid {
            origin: self.origin.to_owned(),
            line,
            key,
            message,
        }
    }

    /// A deserialisation error: the key from its path, the line from its span, the message
    /// as serde words it with its Rust type names in TOML's words.
    fn serde_error(&self, e: &serde_path_to_error::Error<toml::de::Error>) -> SceneError {
        let span = e.inner().span().unwrap_or(0..0);
        let line = line_of(self.text, span.start);
        let key = match e.path().to_string() {
            p if p == "." => "(top level)".to_owned(),
            p => p,
        };
        // `[[name]]` where a single `[name]` table belongs: serde reads the array as the
        // struct's fields in order, so the error is that the first element (a table) is
        // not the first field's type.
        let mut segs: Vec<Seg> = e
            .path()
            .iter()
            .map(|s| match s {
                serde_path_to_error::Segment::Seq { index } => Seg::Index(*index),
                other => Seg::Key(other.to_string()),
            })
            .collect();
        if segs.last() == Some(&Seg::Index(0))
            && e.inner().message().starts_with("invalid type: map")
        {
            segs.pop();
            let found = self.walk(&segs);
            if found.len() == segs.len()
                && let Some(array) = found.last()
                && let DeValue::Array(a) = array.get_ref()
                && a.iter().all(|v| v.get_ref().is_table())
                && self
                    .text
                    .get(span.clone())
                    .is_some_and(|s| s.trim_start().starts_with("[["))
            {
                let key = key.trim_end_matches("[0]");
                let message =
                    format!("expected a single [{key}] table, found an array of tables [[{key}]]");
                return self.invalid(line, key.to_owned(), message);
            }
        }
        let mut message = toml_words(e.inner().message().trim());
        if message.chars().count() > MAX_MESSAGE_CHARS {
            message = message.chars().take(MAX_MESSAGE_CHARS).collect::<String>() + "...";
        }
        self.invalid(line, key, message)
    }

    /// A check's error: its key's line, and the value as written in the file.
    pub(super) fn field_error(&self, mut e: FieldError) -> SceneError {
        let path = parse_path(&e.field);
        let line = self
            .span_of(&path)
            .map(|s| line_of(self.text, s.start))
            .unwrap_or(1);
        if e.found.is_some()
            && let Some(raw) = self.raw_value(&path)
        {
            e.found = Some(raw);
        }
        self.invalid(line, e.field.clone(), e.describe())
    }

    /// The values along `path`, from the first step down, as far as they exist.
    fn walk(&self, path: &[Seg]) -> Vec<&Spanned<DeValue<'a>>> {
        let mut table = self.root.get_ref();
        let mut out: Vec<&Spanned<DeValue<'a>>> = Vec::new();
        for seg in path {
            let next = match (seg, out.last().map(|v| v.get_ref())) {
                (Seg::Key(k), None) => table.get(k.as_str()),
                (Seg::Key(k), Some(DeValue::Table(t))) => {
                    table = t;
                    table.get(k.as_str())
                }
                (Seg::Index(i), Some(DeValue::Array(a))) => a.get(*i),
                _ => None,
            };
            match next {
                Some(v) => out.push(v),
                None => break,
            }
        }
        out
    }

    /// Span of the value at `path`, or of the deepest existing ancestor.
    fn span_of(&self, path: &[Seg]) -> Option<Range<usize>> {
        self.walk(path).last().map(|v| v.span())
    }

    /// The raw text of the value at `path` if it exists exactly there and is no table or
    /// array.
    fn raw_value(&self, path: &[Seg]) -> Option<String> {
        let found = self.walk(path);
        let v = found.last().filter(|_| found.len() == path.len())?;
        match v.get_ref() {
            DeValue::Table(_) | DeValue::Array(_) => None,
            _ => self.text.get(v.span()).map(|s| s.trim().to_owned()),
        }
    }
}

/// serde's message with the Rust type it expected named as a scene file writes it
/// (`expected u32` → `expected a non-negative integer no larger than 4294967295`); a
/// message that names no such type is returned as it is.
fn toml_words(message: &str) -> String {
    let Some((head, expected)) = message.rsplit_once(", expected ") else {
        return message.to_owned();
    };
    let words = match expected {
        "u8" => format!("a non-negative integer no larger than {}", u8::MAX),
        "u16" => format!("a non-negative integer no larger than {}", u16::MAX),
        "u32" => format!("a non-negative integer no larger than {}", u32::MAX),
        "u64" | "usize" => "a non-negative integer".to_owned(),
        "i8" | "i16" | "i32" | "i64" | "isize" => "an integer".to_owned(),
        "f32" | "f64" => "a number".to_owned(),
        "a boolean" => "true or false".to_owned(),
        "a string" => "a string in quotes".to_owned(),
        "a sequence" => "an array".to_owned(),
        "a map" => "a table".to_owned(),
        e if e.starts_with("struct ") => "a table".to_owned(),
        _ => return message.to_owned(),
    };
    format!("{head}, expected {words}")
}

/// 1-based line of byte offset `pos`.
pub(super) fn line_of(text: &str, pos: usize) -> usize {
    let pos = pos.min(text.len());
    text.as_bytes()[..pos]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// One step of a dotted key path.
#[derive(Clone, Debug, PartialEq)]
enum Seg {
    Key(String),
    Index(usize),
}

/// Splits `species[1].params.height` into segments.
fn parse_path(path: &str) -> Vec<Seg> {
    let mut out = Vec::new();
    for part in path.split('.') {
        let mut rest = part;
        if let Some(b) = rest.find('[') {
            if b > 0 {
                out.push(Seg::Key(rest[..b].to_owned()));
            }
            rest = &rest[b..];
            while let Some(stripped) = rest.strip_prefix('[') {
                let Some(end) = stripped.find(']') else { break };
                if let Ok(i) = stripped[..end].parse() {
                    out.push(Seg::Index(i));
                }
                rest = &stripped[end + 1..];
            }
        } else if !rest.is_empty() {
            out.push(Seg::Key(rest.to_owned()));
        }
    }
    out
}

#[cfg(test)]
mod tests;
