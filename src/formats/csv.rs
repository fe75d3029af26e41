//! The one CSV reader of the project (rules in formats/README.md, "CSV files"): every CSV
//! we read goes through [`read_records`], so headers, comments, quoting and errors behave
//! the same in every format.
//!
//! The `csv` crate splits the text (quotes, trimming, line numbers); each row is then
//! deserialized into the caller's serde record through a small map deserializer of our
//! own, so that every error knows its column and every `f64` is checked to be finite
//! (the `csv` crate's own deserializer forgets the column of custom errors).

use super::{FormatError, Result};
use serde::de::{self, DeserializeOwned, IntoDeserializer, Visitor};
use std::fmt;
use std::path::Path;

/// What to do with header columns that are neither required nor optional.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extra {
    /// An unknown column is an error naming it (a misspelt optional column must not be
    /// silently ignored).
    Refuse,
    /// Unknown columns are read over (files whose layout may grow, e.g. truth files).
    Ignore,
}

/// The columns a file format expects (lower case).
#[derive(Debug, Clone, Copy)]
pub struct Layout<'a> {
    pub required: &'a [&'a str],
    pub optional: &'a [&'a str],
    pub extra: Extra,
}

/// A file's data rows as records, with the header's column names (trimmed, lower case).
#[derive(Debug, Clone)]
pub struct Table<T> {
    pub columns: Vec<String>,
    /// 1-based line number of the header.
    pub header_line: usize,
    /// Each record with the 1-based line number it starts on.
    pub rows: Vec<(usize, T)>,
}

impl<T> Table<T> {
    /// Whether the header has `column` (lower case).
    pub fn has(&self, column: &str) -> bool {
        self.columns.iter().any(|c| c == column)
    }
}

/// Reads a CSV file into records of type `T`, whose serde field names are the (lower-case)
/// column names; `Option` fields are `None` when the column is absent or the cell empty.
///
/// Rules: a header line is mandatory, its names are trimmed and case-insensitive; blank
/// lines and lines whose first non-blank character is `#` are comments wherever they are;
/// fields are comma-separated, trimmed, and may be quoted (`"a, b"`); a row may leave off
/// trailing cells (they read as empty) but not have more cells than the header; numbers
/// must be finite. Every error names the file, the line and, where there is one, the column.
pub fn read_records<T: DeserializeOwned>(path: &Path, layout: &Layout) -> Result<Table<T>> {
    let text = std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))?;
    parse_records(path, &text, layout)
}

/// [`read_records`] on text already in memory (`path` names it in errors).
pub fn parse_records<T: DeserializeOwned>(
    path: &Path,
    text: &str,
    layout: &Layout,
) -> Result<Table<T>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // Comments and blank lines are taken out, and line ends made `\n`, before the csv
    // crate sees the text: its positions count neither the empty lines it skips nor the
    // `\n` of a `\r\n`. `original[k]` is the file's line of the kept line k + 1.
    let mut cleaned = String::with_capacity(text.len());
    let mut original = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let t = l.trim_start();
        if !t.is_empty() && !t.starts_with('#') {
            cleaned.push_str(l);
            cleaned.push('\n');
            original.push(i + 1);
        }
    }
    let mut reader = ::csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(::csv::Trim::All)
        .from_reader(cleaned.as_bytes());
    let mut records = reader.records();
    let line_at = |p: Option<&::csv::Position>| {
        p.and_then(|p| original.get((p.line() as usize).checked_sub(1)?))
            .copied()
            .unwrap_or(0)
    };
    let line_of = |r: &::csv::StringRecord| line_at(r.position());
    let syntax = |e: ::csv::Error| {
        let line = line_at(e.position());
        FormatError::at(path, line, None, e.to_string())
    };
    let header = match records.next() {
        None => return Err(FormatError::invalid(path, "empty file: no header line")),
        Some(r) => r.map_err(syntax)?,
    };
    let header_line = line_of(&header);
    let columns: Vec<String> = header.iter().map(|h| h.to_ascii_lowercase()).collect();
    check_header(path, header_line, &columns, layout)?;
    let mut rows = Vec::new();
    for r in records {
        let r = r.map_err(syntax)?;
        let line = line_of(&r);
        if r.len() > columns.len() {
            return Err(FormatError::at(
                path,
                line,
                None,
                format!("{} fields, the header has {}", r.len(), columns.len()),
            ));
        }
        let fields: Vec<&str> = r.iter().collect();
        let value = T::deserialize(RowDeserializer {
            columns: &columns,
            fields: &fields,
            next: 0,
        })
        .map_err(|e| FormatError::at(path, line, e.column, e.message))?;
        rows.push((line, value));
    }
    Ok(Table {
        columns,
        header_line,
        rows,
    })
}

fn check_header(path: &Path, line: usize, columns: &[String], layout: &Layout) -> Result<()> {
    let expected = || {
        let mut s = layout.required.join(",");
        if !layout.optional.is_empty() {
            s.push_str(&format!("[,{}]", layout.optional.join(",")));
        }
        s
    };
    for (i, c) in columns.iter().enumerate() {
        if columns[..i].contains(c) {
            return Err(FormatError::at(
                path,
                line,
                Some(c.clone()),
                "the column appears twice in the header",
            ));
        }
        let known = layout.required.contains(&c.as_str()) || layout.optional.contains(&c.as_str());
        if !known && layout.extra == Extra::Refuse {
            let message = if c.is_empty() {
                format!("column {} of the header has no name", i + 1)
            } else {
                format!(
                    "unknown column {c:?} in the header; expected {}",
                    expected()
                )
            };
            return Err(FormatError::at(path, line, None, message));
        }
    }
    if let Some(missing) = layout
        .required
        .iter()
        .find(|r| !columns.iter().any(|c| c == *r))
    {
        return Err(FormatError::at(
            path,
            line,
            None,
            format!(
                "no column {missing:?} in the header (found {:?}; expected {})",
                columns.join(","),
                expected()
            ),
        ));
    }
    Ok(())
}

/// A deserialization error with the column it happened in.
#[derive(Debug)]
struct CellError {
    column: Option<String>,
    message: String,
}

impl fmt::Display for CellError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for CellError {}

impl de::Error for CellError {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        CellError {
            column: None,
            message: msg.to_string(),
        }
    }
}

/// One row as a map from column name to cell.
struct RowDeserializer<'a> {
    columns: &'a [String],
    fields: &'a [&'a str],
    next: usize,
}

impl<'de> de::Deserializer<'de> for RowDeserializer<'_> {
    type Error = CellError;

    fn deserialize_any<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_map(self)
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf
        option unit unit_struct newtype_struct seq tuple tuple_struct map struct enum
        identifier ignored_any
    }
}

impl<'de> de::MapAccess<'de> for RowDeserializer<'_> {
    type Error = CellError;

    fn next_key_seed<K: de::DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> std::result::Result<Option<K::Value>, CellError> {
        match self.columns.get(self.next) {
            None => Ok(None),
            Some(c) => seed.deserialize(c.as_str().into_deserializer()).map(Some),
        }
    }

    fn next_value_seed<V: de::DeserializeSeed<'de>>(
        &mut self,
        seed: V,
    ) -> std::result::Result<V::Value, CellError> {
        let i = self.next;
        self.next += 1;
        // Trailing cells left off read as empty.
        let cell = Cell(self.fields.get(i).copied().unwrap_or(""));
        seed.deserialize(cell).map_err(|mut e| {
            e.column.get_or_insert_with(|| self.columns[i].clone());
            e
        })
    }
}

/// One cell's text.
struct Cell<'a>(&'a str);

impl Cell<'_> {
    fn error(&self, what: &str) -> CellError {
        de::Error::custom(if self.0.is_empty() {
            format!("empty, {what} is needed")
        } else {
            format!("{:?} is not {what}", self.0)
        })
    }

    fn integer<T: std::str::FromStr>(&self) -> std::result::Result<T, CellError> {
        self.0.parse().map_err(|_| self.error("an integer"))
    }
}

impl<'de> de::Deserializer<'de> for Cell<'_> {
    type Error = CellError;

    fn deserialize_any<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_str(self.0)
    }

    fn deserialize_f64<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        let v: f64 = self.0.parse().map_err(|_| self.error("a number"))?;
        if !v.is_finite() {
            return Err(de::Error::custom(format!(
                "{:?} is not a finite number",
                self.0
            )));
        }
        visitor.visit_f64(v)
    }

    fn deserialize_f32<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        self.deserialize_f64(visitor)
    }

    fn deserialize_i64<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_i64(self.integer()?)
    }

    fn deserialize_i32<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_i64(self.integer()?)
    }

    fn deserialize_u64<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_u64(self.integer()?)
    }

    fn deserialize_u32<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_u64(self.integer()?)
    }

    fn deserialize_bool<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        match self.0.to_ascii_lowercase().as_str() {
            "true" => visitor.visit_bool(true),
            "false" => visitor.visit_bool(false),
            _ => Err(self.error("true or false")),
        }
    }

    fn deserialize_option<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        if self.0.is_empty() {
            visitor.visit_none()
        } else {
            visitor.visit_some(self)
        }
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _name: &'static str,
        _variants: &'static [&'static str],
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_enum(self.0.into_deserializer())
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_unit<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_unit()
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(
        self,
        visitor: V,
    ) -> std::result::Result<V::Value, CellError> {
        visitor.visit_unit()
    }

    serde::forward_to_deserialize_any! {
        i8 i16 i128 u8 u16 u128 char str string bytes byte_buf unit_struct seq tuple
        tuple_struct map struct identifier
    }
}
