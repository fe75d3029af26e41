//! COLMAP sparse models, text and binary, in the legacy 3-file layout (`cameras`,
//! `images`, `points3D`) and the COLMAP ≥ 3.12 / 4.x 5-file layout (`rigs`, `frames` too).
//!
//! Layouts and byte formats follow `colmap/src/colmap/scene/reconstruction_io_*.cc`
//! (see formats/colmap/README.md). COLMAP has no CRS: coordinates in the model are
//! block-local and the CRS, the block origin and the roles of control/check points travel
//! in a side file ([`SIDE_FILE`]) that COLMAP ignores.
//!
//! I/O streams through `BufReader`/`BufWriter`; a million-point model never exists as one
//! string. Every output file is written to a temporary sibling and renamed.
//!
//! One file per idea, as COLMAP's own sources: the camera models (`camera_models`),
//! the records both encodings share and their poses (`records`), the text and binary
//! encodings (`text`, `binary`), the side file (`side_file`), and the assembly of a
//! [`Block`](crate::block::Block) from a model folder (`read`) and back (`write`).

mod binary;
mod camera_models;
mod read;
mod records;
mod side_file;
mod text;
mod write;

pub use read::read;
pub use side_file::SIDE_FILE;
pub use write::write;

use super::Result;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// COLMAP's invalid `point3D_t` (2⁶⁴ − 1).
const INVALID_POINT3D: u64 = u64::MAX;

/// Observation σ given to COLMAP measurements, which carry none.
pub const DEFAULT_SIGMA_PX: f64 = 1.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Text,
    Binary,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// `cameras`, `images`, `points3D` (COLMAP ≤ 3.11; read by every version).
    Legacy,
    /// Adds `rigs` and `frames` (one trivial rig per camera, one frame per image), as
    /// COLMAP 4.x writes.
    Rigs,
}

#[derive(Debug, Clone, Copy)]
pub struct WriteOptions {
    pub encoding: Encoding,
    pub layout: Layout,
}

impl Default for WriteOptions {
    fn default() -> Self {
        Self {
            encoding: Encoding::Binary,
            layout: Layout::Rigs,
        }
    }
}

/// A model file opened for streaming, with a buffer large enough for bulk records.
fn open(path: &Path) -> Result<BufReader<File>> {
    // A regular file only (formats/README.md, "Input files").
    super::input::open(path).map(|f| BufReader::with_capacity(1 << 20, f))
}
