//! The JSON form of every 3×3 matrix we write and read (rotations, scan interior
//! orientations): row-major, as three rows `[[r11, r12, r13], [r21, r22, r23], [r31, r32,
//! r33]]`, so that `m[i][j]` in any reader (Python, a text editor) is `M(i, j)`.
//!
//! nalgebra's own serde form is a flat array of 9 in column order, which every other tool
//! reads transposed. A flat array is refused on reading: it cannot tell a column-major file
//! from a row-major one (as the DCP manifest's flat `rotation`), and guessing would turn a
//! rotation into its inverse without a word.
//!
//! Use as `#[serde(with = "crate::geometry::serde_matrix::row_major")]`, or
//! `option_row_major` (with `#[serde(default)]`) for an `Option<Matrix3<f64>>`.

use nalgebra::Matrix3;
use serde::{de::Error as _, Deserialize, Deserializer, Serialize, Serializer};

fn to_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// What a matrix field may hold on reading: rows (accepted) or a flat array (refused with
/// a message that says how to write it).
#[derive(Deserialize)]
#[serde(untagged)]
enum Written {
    Rows([[f64; 3]; 3]),
    Flat(Vec<f64>),
}

fn from_written<E: serde::de::Error>(w: Written) -> Result<Matrix3<f64>, E> {
    match w {
        Written::Rows(r) => Ok(Matrix3::from_fn(|i, j| r[i][j])),
        Written::Flat(v) => Err(E::custom(format!(
            "a 3×3 matrix is written as three rows [[r11, r12, r13], [r21, r22, r23], \
             [r31, r32, r33]], not as a flat array of {} numbers (whose order, row- or \
             column-major, cannot be told)",
            v.len()
        ))),
    }
}

/// `Matrix3<f64>` as three rows.
pub mod row_major {
    use super::*;

    pub fn serialize<S: Serializer>(m: &Matrix3<f64>, s: S) -> Result<S::Ok, S::Error> {
        to_rows(m).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Matrix3<f64>, D::Error> {
        let w = Written::deserialize(d)
            .map_err(|_| D::Error::custom("expected a 3×3 matrix as three rows of 3 numbers"))?;
        from_written(w)
    }
}

/// `Option<Matrix3<f64>>` as three rows or `null`; give the field `#[serde(default)]` so
/// that a missing key still reads as `None`.
pub mod option_row_major {
    use super::*;

    pub fn serialize<S: Serializer>(m: &Option<Matrix3<f64>>, s: S) -> Result<S::Ok, S::Error> {
        m.as_ref().map(to_rows).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Matrix3<f64>>, D::Error> {
        let w = Option::<Written>::deserialize(d).map_err(|_| {
            D::Error::custom("expected a 3×3 matrix as three rows of 3 numbers, or null")
        })?;
        w.map(from_written).transpose()
    }
}
