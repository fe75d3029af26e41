//! Format adapters: coordinate reference systems (GDAL/PROJ), GeoTIFF rasters, and the
//! photogrammetric exchange formats. Readers and writers only; no photogrammetry here.

pub mod blocks_exchange;
pub mod colmap;
pub mod control_points;
pub mod convert;
pub mod crs;
pub mod crs_input;
pub mod csv;
pub mod gdal;
pub mod image_open;
pub mod input;
pub mod odm_gcp;
pub mod ortho;
pub mod pos;
pub mod raster;

use std::path::{Path, PathBuf};

/// Errors of the format adapters; each names the file (or CRS) and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A CSV row or header (formats/README.md, "CSV files"): 1-based line, column if known.
    #[error("{path}: line {line}{}: {message}", .column.as_ref().map(|c| format!(", column {c}")).unwrap_or_default())]
    Csv {
        path: PathBuf,
        line: usize,
        column: Option<String>,
        message: String,
    },
    #[error("coordinate reference system {crs:?}: {message}")]
    Crs { crs: String, message: String },
    /// A size or count in the file claims more than the file or a documented limit
    /// allows: refused before anything is allocated or decoded from it.
    #[error("{path}: {what}: {claimed} exceeds {limit}, {basis}")]
    TooLarge {
        path: PathBuf,
        what: String,
        claimed: u64,
        limit: u64,
        basis: String,
    },
    /// An input that is not a regular file (a FIFO, a device, a socket, a folder where a
    /// file is expected) or is reached through a symbolic link cycle: refused before
    /// anything is read from it ([`input`]).
    #[error("{path}: {message}")]
    NotRegularFile { path: PathBuf, message: String },
    #[error("{path}: GDAL: {message}")]
    Gdal { path: PathBuf, message: String },
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
}

pub type Result<T> = std::result::Result<T, FormatError>;

impl FormatError {
    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        FormatError::Invalid {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }
    /// An error at `line` (1-based) and, if given, `column` of a CSV file.
    pub fn at(
        path: impl AsRef<Path>,
        line: usize,
        column: Option<String>,
        message: impl Into<String>,
    ) -> Self {
        FormatError::Csv {
            path: path.as_ref().to_path_buf(),
            line,
            column,
            message: message.into(),
        }
    }
    /// The message without the file name in front, for callers whose own error names
    /// the file.
    pub fn detail(&self) -> String {
        match self {
            FormatError::Io { source, .. } => source.to_string(),
            FormatError::Invalid { message, .. } => message.clone(),
            FormatError::NotRegularFile { message, .. } => message.clone(),
            FormatError::TooLarge {
                what,
                claimed,
                limit,
                basis,
                ..
            } => format!("{what}: {claimed} exceeds {limit}, {basis}"),
            FormatError::Csv {
                line,
                column,
                message,
                ..
            } => match column {
                Some(c) => format!("line {line}, column {c}: {message}"),
                None => format!("line {line}: {message}"),
            },
            e => e.to_string(),
        }
    }
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        FormatError::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    pub fn gdal(path: impl AsRef<Path>, e: gdal::GdalError) -> Self {
        FormatError::Gdal {
            path: path.as_ref().to_path_buf(),
            message: e.to_string(),
        }
    }
}

/// A temporary sibling of `path` to write into before an atomic rename, so that readers
/// never see a half-written output. The extension is kept (GDAL picks drivers by it).
pub fn temporary_sibling(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match path.extension() {
        Some(ext) => format!(
            ".{stem}.part-{}.{}",
            std::process::id(),
            ext.to_string_lossy()
        ),
        None => format!(".{stem}.part-{}", std::process::id()),
    };
    path.with_file_name(name)
}

/// Folders created by [`create_folders`], removed again by [`CreatedFolders::undo`] when
/// the output that needed them failed, so that a failed command leaves no empty output
/// folder behind.
#[derive(Debug, Default)]
pub struct CreatedFolders(Vec<PathBuf>);

/// Creates `dir` and its missing ancestors, remembering which were missing.
pub fn create_folders(dir: &Path) -> Result<CreatedFolders> {
    let mut missing = Vec::new();
    let mut d = Some(dir);
    while let Some(p) = d.filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
        missing.push(p.to_path_buf());
        d = p.parent();
    }
    std::fs::create_dir_all(dir).map_err(|e| FormatError::io(dir, e))?;
    Ok(CreatedFolders(missing))
}

impl CreatedFolders {
    /// Removes the created folders, innermost first; with `contents`, the outermost one
    /// is removed with whatever it holds (everything in it was written by the failed
    /// output, as it did not exist before), else only folders that are empty.
    pub fn undo(self, contents: bool) {
        if contents {
            if let Some(top) = self.0.last() {
                let _ = std::fs::remove_dir_all(top);
            }
            return;
        }
        for d in &self.0 {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// Writes a file atomically: the closure writes into a temporary sibling which is renamed
/// over `path` only when it succeeded; on failure the temporary file is removed, and so
/// are the folders created for it.
pub fn write_atomically<T>(path: &Path, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let created = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => create_folders(dir)?,
        None => CreatedFolders::default(),
    };
    let tmp = temporary_sibling(path);
    let result = match write(&tmp) {
        Ok(v) => std::fs::rename(&tmp, path)
            .map(|()| v)
            .map_err(|e| FormatError::io(path, e)),
        Err(e) => Err(e),
    };
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
        created.undo(false);
    }
    result
}

/// Writes bytes atomically (text formats, JSON reports).
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |tmp| {
        std::fs::write(tmp, bytes).map_err(|e| FormatError::io(path, e))
    })
}

/// The pixel-unit frame camera equivalent to a camera, for formats that only know frame
/// cameras (COLMAP, BlocksExchange in pixels). A film camera converts exactly when its
/// scan interior orientation is a pure scale with y up (axis-aligned scan, no shear);
/// any other scan needs resampling first (`matching::fiducial::frame_image`, which the
/// run's products do), which is refused here rather than approximated.
pub fn frame_equivalent(
    camera: &crate::geometry::Camera,
) -> std::result::Result<crate::geometry::FrameCamera, String> {
    use crate::geometry::{Camera, FrameCamera};
    match camera {
        Camera::Frame(f) => Ok(f.clone()),
        Camera::Film(c) => {
            let a = &c.interior.pixel_to_mm;
            let scale = a[(0, 0)].abs().max(a[(1, 1)].abs());
            let tol = 1e-12 * scale;
            if a[(0, 1)].abs() > tol
                || a[(1, 0)].abs() > tol
                || a[(2, 0)] != 0.0
                || a[(2, 1)] != 0.0
                || a[(2, 2)] != 1.0
                || a[(0, 0)] <= 0.0
                || a[(1, 1)] >= 0.0
            {
                return Err(
                    "film camera whose scan interior orientation is not an axis-aligned scale \
                     (x right, y up) has no exact frame-camera equivalent; resample the scan \
                     into its fiducial frame first (the products of `cloudcontrol run` do)"
                        .into(),
                );
            }
            let (sx, sy) = (a[(0, 0)], -a[(1, 1)]);
            Ok(FrameCamera {
                width: c.width,
                height: c.height,
                fx: c.focal_mm / sx,
                fy: c.focal_mm / sy,
                cx: (c.principal_point_mm[0] - a[(0, 2)]) / sx,
                cy: (a[(1, 2)] - c.principal_point_mm[1]) / sy,
                distortion: c.distortion,
            })
        }
    }
}
