//! ContextCapture / iTwin Capture Modeler BlocksExchange XML (read any version, write 2.1).
//!
//! Conventions (formats/blocks-exchange/README.md, design/formats-notes.md §1):
//! - `<Rotation>` is world→camera in the photogroup's `<CameraOrientation>` axes:
//!   our `R = O·M` (`O = I` for XRightYDown, `diag(1,−1,−1)` for XRightYUp).
//!   Omega/Phi/Kappa (degrees) give `M = R3(κ)·R2(φ)·R1(ω)`.
//! - `<Center>` is the projection centre.
//! - Pixel coordinates have their origin at the centre of the top-left pixel: ours are
//!   half a pixel larger.
//! - Brown tangential terms are swapped relative to OpenCV: `p1 = P2`, `p2 = P1`.
//! - `FocalLength`, `SensorSize` (largest sensor dimension), `PixelSize`, `xmm/ymm` in mm;
//!   `FocalLengthPixels` and `PrincipalPoint x/y` in pixels; `xmm/ymm` of a principal point
//!   from the sensor centre, of a measurement from the principal point, axes per
//!   CameraOrientation.
//!
//! Control point categories map onto σ: Horizontal has an infinite vertical σ (its height
//! is unknown and stored as 0), Vertical an infinite horizontal σ.
//!
//! One file per concern: the XML schema (`xml`), the conventions (`conventions`), the
//! reader (`read`) and the writer (`write`).

mod conventions;
mod read;
mod write;
mod xml;

pub use conventions::{camera_orientation_matrix, matrix_from_opk_degrees};
pub use read::{read, read_str};
pub use write::{to_string, write, WriteOptions};
pub use xml::Document;
