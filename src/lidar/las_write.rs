//! Writing LAS/LAZ files of our own points (synthetic LiDAR tiles, an epoch's surface as
//! points): LAS 1.4, point format 6, millimetre scale, the CRS as an OGC WKT VLR, and
//! fixed header fields (date, software) so that a file is byte-identical between runs.

use crate::formats::{self, FormatError};
use std::path::Path;

/// The header of a new file: coordinates stored as millimetres from `offset`, compressed
/// (LAZ) when `laz`, in the CRS `wkt`.
pub fn new_header(offset: [f64; 3], laz: bool, wkt: &str) -> Result<las::Header, String> {
    let mut builder = las::Builder::from((1, 4));
    builder.point_format = las::point::Format::new(6).map_err(|e| e.to_string())?;
    builder.point_format.is_compressed = laz;
    builder.date = chrono::NaiveDate::from_yo_opt(2024, 150);
    builder.generating_software = format!("cloudcontrol {}", crate::VERSION);
    builder.system_identifier = "cloudcontrol".into();
    builder.gps_time_type = las::GpsTimeType::Standard;
    let mm = |offset| las::Transform {
        scale: 0.001,
        offset,
    };
    builder.transforms = las::Vector {
        x: mm(offset[0]),
        y: mm(offset[1]),
        z: mm(offset[2]),
    };
    builder.has_wkt_crs = true;
    builder.vlrs.push(las::Vlr {
        user_id: "LASF_Projection".into(),
        record_id: 2112,
        description: "OGC WKT coordinate system".into(),
        data: {
            let mut d = wkt.as_bytes().to_vec();
            d.push(0);
            d
        },
    });
    builder.into_header().map_err(|e| e.to_string())
}

/// Writes `points` into a new file at `path` with `header`, atomically: a failure leaves
/// nothing, not even the temporary file. Returns how many were written. A point the
/// header's scale and offset cannot hold is an error naming it, and a panic in the writer
/// (it closes itself when dropped and panics if that fails, after a failed point say) is
/// caught and reported as one.
pub fn write_points(
    path: &Path,
    header: las::Header,
    points: impl IntoIterator<Item = formats::Result<las::Point>>,
) -> formats::Result<u64> {
    let fail = |m: String| FormatError::invalid(path, m);
    let t = *header.transforms();
    formats::write_atomically(path, |tmp| {
        let write = std::panic::AssertUnwindSafe(|| {
            let file = std::fs::File::create(tmp).map_err(|e| FormatError::io(tmp, e))?;
            let mut w = las::Writer::new(std::io::BufWriter::new(file), header)
                .map_err(|e| fail(format!("cannot write LAS: {e}")))?;
            let mut n = 0u64;
            for p in points {
                let p = p?;
                storable(&t, &p).map_err(|m| fail(format!("point {n} written: {m}")))?;
                w.write_point(p)
                    .map_err(|e| fail(format!("cannot write point {n}: {e}")))?;
                n += 1;
            }
            w.close()
                .map_err(|e| fail(format!("cannot finish LAS: {e}")))?;
            Ok(n)
        });
        std::panic::catch_unwind(write).unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(fail(format!("the LAS writer failed: {what}")))
        })
    })
}

/// Whether the header's scale and offset `t` can hold point `p` (finite, within the
/// 32-bit integers of the format); the coordinate that cannot, said.
pub(crate) fn storable(t: &las::Vector<las::Transform>, p: &las::Point) -> Result<(), String> {
    for (axis, v, t) in [("x", p.x, t.x), ("y", p.y, t.y), ("z", p.z, t.z)] {
        if !v.is_finite() || t.inverse(v).is_err() {
            return Err(format!(
                "{axis} = {v} cannot be stored with scale {} and offset {}",
                t.scale, t.offset
            ));
        }
    }
    Ok(())
}
