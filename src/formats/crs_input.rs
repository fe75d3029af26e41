//! Which CRS definitions reach GDAL/PROJ. CRS strings come from data files (DCP manifests,
//! BlocksExchange `<Definition>`, LAS WKT VLRs, project files) that travel between
//! organisations; GDAL's `SetFromUserInput` would fetch an `http://` definition, read a
//! definition from a file named by the string, and PROJ opens the grid files a definition
//! names (`+nadgrids`, `+geoidgrids`, `+init`, WKT `PARAMETERFILE`, a PROJ4 `EXTENSION`)
//! — from PROJ's CDN when its network is on. So a definition is classified here and
//! handed to the one GDAL importer of its kind, and every reference to a URL or a file is
//! refused before GDAL sees it.
//!
//! Accepted: `EPSG:n` and `EPSG:n+m` (horizontal + vertical), WKT 1 and 2, PROJJSON, and
//! PROJ strings (`+proj=…`). A grid may be named only by its bare file name
//! (`egm96_15.gtx`, `@null`; GDAL 2 wrote such names into the WKT of vertical CRSs), which
//! PROJ looks up in its own resource directories; a grid named by a path or a URL is
//! refused, and so are init files (`+init`).

use super::{FormatError, Result};

/// What a definition is, and so which GDAL importer reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrsSyntax {
    /// `EPSG:n` or `EPSG:n+m`: the PROJ database, nothing else.
    Epsg,
    Wkt,
    ProjJson,
    ProjString,
}

/// PROJ string keys whose value names a file other than a grid.
const FILE_KEYS: &[&str] = &["init", "file", "catalog"];

/// PROJ string keys whose value is a list of grids.
const GRID_KEYS: &[&str] = &["nadgrids", "geoidgrids", "grids"];

/// Whether `value` names grids by bare file names only (`a.gtx,@b.tif`): no folder, no
/// URL, nothing hidden or relative, so PROJ can only find them in its resource folders.
fn bare_grid_names(value: &str) -> bool {
    value.split(',').all(|g| {
        let g = g.strip_prefix('@').unwrap_or(g);
        !g.is_empty()
            && !g.starts_with('.')
            && g.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"_.-".contains(&b))
    })
}

fn grid_error(what: &str, value: &str) -> String {
    format!(
        "{what} names a grid by path or URL ({}); a grid in a CRS from data may only be \
         named by its bare file name, found in PROJ's resource folders",
        excerpt(value)
    )
}

/// WKT keywords that start a CRS in GDAL's list of WKT openers (its `importFromWkt` is
/// only reached for these; anything else would fall through to file and URL lookups).
const WKT_KEYWORDS: &[&str] = &[
    "GEOGCS",
    "PROJCS",
    "GEOCCS",
    "COMPD_CS",
    "VERT_CS",
    "LOCAL_CS",
    "FITTED_CS",
    "GEODCRS",
    "GEOGCRS",
    "GEODETICCRS",
    "GEOGRAPHICCRS",
    "BASEGEODCRS",
    "BASEGEOGCRS",
    "PROJCRS",
    "PROJECTEDCRS",
    "BASEPROJCRS",
    "VERTCRS",
    "VERTICALCRS",
    "BASEVERTCRS",
    "COMPOUNDCRS",
    "BOUNDCRS",
    "ENGCRS",
    "ENGINEERINGCRS",
    "PARAMETRICCRS",
    "TIMECRS",
    "DERIVEDPROJCRS",
];

/// PROJJSON types GDAL reads as a CRS.
const PROJJSON_TYPES: &[&str] = &[
    "GeodeticCRS",
    "GeographicCRS",
    "ProjectedCRS",
    "VerticalCRS",
    "CompoundCRS",
    "BoundCRS",
    "EngineeringCRS",
    "ParametricCRS",
    "TemporalCRS",
    "DerivedGeodeticCRS",
    "DerivedGeographicCRS",
    "DerivedProjectedCRS",
    "DerivedVerticalCRS",
];

/// Longest definition read (a WKT 2 compound CRS with a bound transformation is ~10 KB).
pub const MAX_DEFINITION_BYTES: usize = 64 * 1024;

/// The syntax of a trimmed, non-empty definition, or an error naming the definition and
/// the reference that is refused.
pub fn classify(definition: &str) -> Result<CrsSyntax> {
    let refuse = |message: String| FormatError::Crs {
        crs: excerpt(definition),
        message,
    };
    if definition.len() > MAX_DEFINITION_BYTES {
        return Err(refuse(format!(
            "definition of {} bytes exceeds {MAX_DEFINITION_BYTES}, the longest CRS read",
            definition.len()
        )));
    }
    let syntax = if is_epsg(definition) {
        CrsSyntax::Epsg
    } else if definition.starts_with('{') {
        check_projjson(definition).map_err(refuse)?;
        CrsSyntax::ProjJson
    } else if definition.starts_with('+') {
        check_proj_string(definition).map_err(refuse)?;
        CrsSyntax::ProjString
    } else if wkt_keyword(definition).is_some() {
        check_wkt(definition).map_err(refuse)?;
        CrsSyntax::Wkt
    } else {
        return Err(refuse(format!(
            "{}; a CRS is given as EPSG:n (or EPSG:n+m), WKT, PROJJSON or a PROJ string \
             (+proj=…), and definitions are never fetched or read from files",
            what_it_is(definition)
        )));
    };
    Ok(syntax)
}

/// The first 80 characters, for messages.
pub fn excerpt(definition: &str) -> String {
    let mut s: String = definition.chars().take(80).collect();
    if s.len() < definition.len() {
        s.push('…');
    }
    s
}

fn what_it_is(definition: &str) -> &'static str {
    let lower = definition.to_ascii_lowercase();
    if lower.contains("://") || lower.starts_with("/vsi") {
        "a URL is not a CRS definition (CRSs named by data are never fetched)"
    } else if definition.starts_with('@')
        || definition.starts_with('/')
        || definition.starts_with('.')
        || definition.starts_with('~')
        || definition.contains('\\')
        || lower.starts_with("dict:")
        || lower.starts_with("file:")
    {
        "a file name is not a CRS definition (CRSs named by data are never read from files)"
    } else {
        "not a CRS definition cloudcontrol reads"
    }
}

fn is_epsg(s: &str) -> bool {
    let Some(rest) = s.get(..5).filter(|p| p.eq_ignore_ascii_case("EPSG:")) else {
        return false;
    };
    let rest = &s[rest.len()..];
    let code = |c: &str| {
        let c = c.trim();
        !c.is_empty() && c.len() <= 9 && c.bytes().all(|b| b.is_ascii_digit())
    };
    match rest.split_once('+') {
        None => code(rest),
        Some((h, v)) => code(h) && code(v),
    }
}

fn wkt_keyword(s: &str) -> Option<&str> {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    let (word, rest) = s.split_at(end);
    let opens = rest.trim_start().starts_with(['[', '(']);
    WKT_KEYWORDS
        .iter()
        .any(|k| k.eq_ignore_ascii_case(word))
        .then_some(word)
        .filter(|_| opens)
}

fn has_url(s: &str) -> bool {
    s.contains("://") || s.to_ascii_lowercase().contains("/vsi")
}

/// A PROJ string: `+key[=value]` tokens; keys that name files are refused (except the
/// built-in `@null` grid), and so is any value that looks like a path or a URL.
fn check_proj_string(s: &str) -> std::result::Result<(), String> {
    let mut has_proj = false;
    for token in s.split_whitespace() {
        let Some(kv) = token.strip_prefix('+') else {
            return Err(format!(
                "PROJ string token {token:?} does not start with '+'"
            ));
        };
        let (key, value) = kv.split_once('=').unwrap_or((kv, ""));
        let key = key.to_ascii_lowercase();
        has_proj |= key == "proj";
        if FILE_KEYS.contains(&key.as_str()) {
            return Err(format!(
                "+{key} names a file ({value:?}); PROJ strings from data may not name \
                 init or other files (give EPSG:n, or a definition without +{key})"
            ));
        }
        if GRID_KEYS.contains(&key.as_str()) {
            if !bare_grid_names(value) {
                return Err(grid_error(&format!("+{key}"), value));
            }
            continue;
        }
        if has_url(value) || value.contains(['/', '\\', '~', '@']) {
            return Err(format!(
                "+{key}={value} looks like a path or URL; PROJ strings from data may not \
                 name files or URLs"
            ));
        }
    }
    if !has_proj {
        return Err("PROJ string without +proj=".into());
    }
    Ok(())
}

/// WKT: a small scan of keywords and quoted strings (`""` escapes a quote). Refused: a
/// grid named by path or URL (`PARAMETERFILE`, `EXTENSION["PROJ4_GRIDS",…]`, a PROJ
/// string in `EXTENSION["PROJ4",…]`), and a URL in any string except a WKT 2 `URI[…]`
/// (an identifier PROJ never dereferences).
fn check_wkt(s: &str) -> std::result::Result<(), String> {
    let mut stack: Vec<String> = Vec::new();
    let mut word = String::new();
    // Strings of the innermost element so far (EXTENSION's name, then its value).
    let mut strings: Vec<Vec<String>> = Vec::new();
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' => {
                let mut text = String::new();
                loop {
                    match chars.next() {
                        None => return Err("unterminated quoted string".into()),
                        Some('"') if chars.peek() == Some(&'"') => {
                            chars.next();
                            text.push('"');
                        }
                        Some('"') => break,
                        Some(ch) => text.push(ch),
                    }
                }
                let element = stack.last().map(String::as_str).unwrap_or("");
                if element != "URI" && has_url(&text) {
                    return Err(format!(
                        "{element}[…] holds a URL ({}); CRSs from data never name URLs",
                        excerpt(&text)
                    ));
                }
                if let Some(list) = strings.last_mut() {
                    list.push(text);
                }
                word.clear();
            }
            '[' | '(' => {
                let element = word.trim().to_ascii_uppercase();
                stack.push(element);
                strings.push(Vec::new());
                word.clear();
            }
            ']' | ')' => {
                let element = stack.pop().ok_or("unbalanced brackets")?;
                let list = strings.pop().unwrap_or_default();
                if element == "EXTENSION" {
                    check_extension(&list)?;
                }
                if let Some(file) = list.get(1).filter(|_| element == "PARAMETERFILE") {
                    if !bare_grid_names(file) {
                        return Err(grid_error("PARAMETERFILE[…]", file));
                    }
                }
                word.clear();
            }
            ',' => word.clear(),
            c => word.push(c),
        }
    }
    if !stack.is_empty() {
        return Err("unbalanced brackets".into());
    }
    Ok(())
}

fn check_extension(strings: &[String]) -> std::result::Result<(), String> {
    let name = strings.first().map(|n| n.to_ascii_uppercase());
    match (name.as_deref(), strings.get(1)) {
        (Some("PROJ4_GRIDS"), Some(grids)) if !bare_grid_names(grids) => {
            Err(grid_error("EXTENSION[\"PROJ4_GRIDS\",…]", grids))
        }
        (Some("PROJ4"), Some(proj)) => {
            check_proj_string(proj).map_err(|e| format!("EXTENSION[\"PROJ4\",…]: {e}"))
        }
        _ => Ok(()),
    }
}

/// PROJJSON: a CRS type at the top; a parameter whose value is a string (PROJ writes grid
/// file names there) holds bare file names only, and no URL except in the `$schema` and
/// `uri` identifiers.
fn check_projjson(s: &str) -> std::result::Result<(), String> {
    let v: serde_json::Value =
        serde_json::from_str(s).map_err(|e| format!("not valid PROJJSON ({e})"))?;
    let t = v.get("type").and_then(|t| t.as_str()).unwrap_or("");
    if !PROJJSON_TYPES.contains(&t) {
        return Err(format!("PROJJSON of type {t:?} is not a CRS"));
    }
    walk_json(&v, "")
}

fn walk_json(v: &serde_json::Value, key: &str) -> std::result::Result<(), String> {
    use serde_json::Value;
    match v {
        Value::String(s) if key != "$schema" && key != "uri" && has_url(s) => Err(format!(
            "\"{key}\" holds a URL ({}); CRSs from data never name URLs",
            excerpt(s)
        )),
        Value::Object(o) => {
            for (k, x) in o {
                walk_json(x, k)?;
            }
            Ok(())
        }
        Value::Array(a) => {
            for x in a {
                if key == "parameters" {
                    if let Some(Value::String(f)) = x
                        .get("value")
                        .filter(|f| f.as_str().is_some_and(|f| !bare_grid_names(f)))
                    {
                        let name = x.get("name").and_then(|n| n.as_str()).unwrap_or("");
                        return Err(grid_error(&format!("parameter {name:?}"), f));
                    }
                }
                walk_json(x, key)?;
            }
            Ok(())
        }
        _ => Ok(()),
    }
}
