//! The one CSV reader of the project (rules in formats/README.md, "CSV files"): every CSV
//! we read goes through [`read_records`], so headers, comments, quoting and errors behave
//! the same in every format.
//!
//! The `csv` crate splits the text (quotes, trimming, line numbers); each row is then
//! deserialized into the caller's serde record through a small map deserializer of our
//! own, so that every error knows its column and every `f64` is checked to be finite
//! (the `csv` crate's own deserializer forgets the column of custom errors).

use super::{input, FormatError, Result};
use serde::de::{self, DeserializeOwned, IntoDeserializer, Visitor};
use std::fmt;
use std::io::{BufRead, Read};
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
///
/// The file must be a regular file of at most [`input::Limits::csv_bytes`]; it is read
/// line by line, each line (and each quoted record) at most
/// [`input::Limits::csv_line_bytes`], the header at most [`input::Limits::csv_columns`]
/// columns (formats/README.md, "Input files").
pub fn read_records<T: DeserializeOwned>(path: &Path, layout: &Layout) -> Result<Table<T>> {
    read_records_renamed(path, layout, &|_| None)
}

/// What a format's old header is read as: given the header's names as written (trimmed,
/// case kept), the names to read its columns by, or `None` to read them as usual.
pub type Rename<'a> = &'a dyn Fn(&[&str]) -> Option<Vec<String>>;

/// [`read_records`] for a format whose columns were renamed and whose old header is still
/// read: `rename` sees the header as written, case kept, and may give the names to read
/// its columns by. The one place where case tells columns apart: `resect --points`'s old
/// header `x,y,X,Y,Z` (pixel, then world) is read as `col,row,x,y,z`.
pub fn read_records_renamed<T: DeserializeOwned>(
    path: &Path,
    layout: &Layout,
    rename: Rename,
) -> Result<Table<T>> {
    let file = input::open_capped(path, input::Cap::csv())?;
    parse_from(
        path,
        std::io::BufReader::with_capacity(1 << 16, file),
        layout,
        rename,
    )
}

/// [`read_records`] on text already in memory (`path` names it in errors).
pub fn parse_records<T: DeserializeOwned>(
    path: &Path,
    text: &str,
    layout: &Layout,
) -> Result<Table<T>> {
    parse_from(path, text.as_bytes(), layout, &|_| None)
}

/// The lines of a CSV text as the `csv` crate reads them: comments and blank lines taken
/// out and line ends made `\n` (its positions count neither the empty lines it skips nor
/// the `\r` of a `\r\n`), each line and each record bounded. `original[k]` is the file's
/// line of the kept line k + 1.
struct Cleaned<R> {
    lines: input::Lines<R>,
    original: Vec<usize>,
    pending: Vec<u8>,
    at: usize,
    /// Bytes handed to the `csv` crate since its last record ended: a quoted field that
    /// runs on over many lines is cut off at the line cap too.
    fed: u64,
    record_cap: u64,
    /// Whether the last line ended inside a quoted field ([`blanks_before_quotes`]).
    in_quotes: bool,
    /// Why reading stopped, kept typed (the `csv` crate sees an I/O error).
    error: Option<FormatError>,
}

impl<R: BufRead> Read for Cleaned<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        while self.at == self.pending.len() {
            let (no, line) = match self.lines.next_bytes() {
                None => return Ok(0),
                Some(Ok(l)) => l,
                Some(Err(e)) => {
                    self.error = Some(e);
                    return Err(std::io::Error::other("line too long"));
                }
            };
            let line = match (no, line.strip_prefix("\u{feff}".as_bytes())) {
                (1, Some(rest)) => rest,
                _ => line,
            };
            let t = line.trim_ascii_start();
            if t.is_empty() || t.starts_with(b"#") {
                continue;
            }
            self.pending.clear();
            blanks_before_quotes(line, &mut self.in_quotes, &mut self.pending);
            self.pending.push(b'\n');
            self.at = 0;
            self.original.push(no);
        }
        let n = out.len().min(self.pending.len() - self.at);
        out[..n].copy_from_slice(&self.pending[self.at..self.at + n]);
        self.at += n;
        self.fed += n as u64;
        if self.fed > self.record_cap {
            let line = self.original.last().copied().unwrap_or(0);
            self.error = Some(FormatError::at(
                self.lines_path(),
                line,
                None,
                format!(
                    "a quoted field runs on past {} bytes, the longest record read (raise \
                     `csv_line` in {})",
                    self.record_cap,
                    input::LIMITS_ENV
                ),
            ));
            return Err(std::io::Error::other("record too long"));
        }
        Ok(n)
    }
}

/// Appends `line` to `out` without the blanks (spaces, tabs) between a field's start and
/// its opening quote: fields are trimmed (formats/README.md), so `a, "b, c"` holds the
/// field `b, c`, but the `csv` crate takes a quote as opening a quoted field only as the
/// field's first character (its trimming comes after the split, and ` "b` would be read
/// as an unquoted field, `c"` as another). `in_quotes` carries a quoted field that runs
/// on over the line end into the next line; blanks inside quotes are kept.
fn blanks_before_quotes(line: &[u8], in_quotes: &mut bool, out: &mut Vec<u8>) {
    let mut field_start = !*in_quotes;
    let mut i = 0;
    while i < line.len() {
        let b = line[i];
        if *in_quotes {
            // `""` inside quotes is one quote; a lone quote closes the field.
            if b == b'"' {
                if line.get(i + 1) == Some(&b'"') {
                    out.extend_from_slice(b"\"\"");
                    i += 2;
                    continue;
                }
                *in_quotes = false;
            }
            out.push(b);
        } else if field_start {
            field_start = false;
            let blanks = line[i..]
                .iter()
                .take_while(|c| **c == b' ' || **c == b'\t')
                .count();
            if line.get(i + blanks) == Some(&b'"') {
                *in_quotes = true;
                out.push(b'"');
                i += blanks + 1;
                continue;
            }
            continue;
        } else {
            if b == b',' {
                field_start = true;
            }
            out.push(b);
        }
        i += 1;
    }
}

impl<R: BufRead> Cleaned<R> {
    fn lines_path(&self) -> &Path {
        self.lines.path()
    }
}

fn parse_from<T: DeserializeOwned, R: BufRead>(
    path: &Path,
    reader: R,
    layout: &Layout,
    rename: Rename,
) -> Result<Table<T>> {
    let limits = input::limits();
    let line_cap = input::Cap::csv_line();
    let cleaned = Cleaned {
        lines: input::Lines::new(reader, path, line_cap),
        original: Vec::new(),
        pending: Vec::new(),
        at: 0,
        fed: 0,
        // The csv crate reads ahead by its buffer (8 KiB) past the end of a record.
        record_cap: line_cap.bytes.saturating_add(64 << 10),
        in_quotes: false,
        error: None,
    };
    let mut reader = ::csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(::csv::Trim::All)
        .from_reader(cleaned);
    let line_at = |reader: &::csv::Reader<Cleaned<R>>, p: Option<&::csv::Position>| {
        p.and_then(|p| {
            reader
                .get_ref()
                .original
                .get((p.line() as usize).checked_sub(1)?)
        })
        .copied()
        .unwrap_or(0)
    };
    // The next record, or None at the end; the reader's own errors kept typed.
    let next =
        |reader: &mut ::csv::Reader<Cleaned<R>>, r: &mut ::csv::StringRecord| -> Result<bool> {
            let got = reader.read_record(r);
            reader.get_mut().fed = 0;
            match got {
                Ok(more) => Ok(more),
                Err(e) => match reader.get_mut().error.take() {
                    Some(typed) => Err(typed),
                    None => {
                        let line = line_at(reader, e.position());
                        Err(FormatError::at(path, line, None, e.to_string()))
                    }
                },
            }
        };
    let mut header = ::csv::StringRecord::new();
    if !next(&mut reader, &mut header)? {
        return Err(FormatError::invalid(path, "empty file: no header line"));
    }
    let header_line = line_at(&reader, header.position());
    if header.len() as u64 > limits.csv_columns {
        return Err(FormatError::TooLarge {
            path: path.to_path_buf(),
            what: format!("line {header_line}: columns of the header"),
            claimed: header.len() as u64,
            limit: limits.csv_columns,
            basis: format!(
                "the most columns a CSV header may have (raise `csv_columns` in {})",
                input::LIMITS_ENV
            ),
        });
    }
    let written: Vec<&str> = header.iter().collect();
    let columns: Vec<String> = rename(&written)
        .filter(|c| c.len() == written.len())
        .unwrap_or_else(|| written.iter().map(|h| h.to_ascii_lowercase()).collect());
    check_header(path, header_line, &columns, layout)?;
    let mut rows = Vec::new();
    let mut r = ::csv::StringRecord::new();
    while next(&mut reader, &mut r)? {
        let line = line_at(&reader, r.position());
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
