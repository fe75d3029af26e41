//! Coordinate reference systems and transformations.
//!
//! We use GDAL's OSR (`OGRCoordinateTransformation`), which is PROJ underneath: GDAL is
//! linked anyway for rasters, so this is one binding to one PROJ instead of two, and it
//! avoids pinning the `proj` crate to the old release that builds against Debian's PROJ.
//! Axis order is always the traditional GIS one (easting/longitude first).

use super::{FormatError, Result};
use gdal::spatial_ref::{AxisMappingStrategy, CoordTransform, SpatialRef};

/// A parsed CRS: from `EPSG:n`, WKT, PROJJSON or a PROJ string.
pub struct Crs {
    definition: String,
    srs: SpatialRef,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Crs({})", self.label())
    }
}

impl Clone for Crs {
    fn clone(&self) -> Self {
        Self::parse(&self.definition).expect("a CRS that parsed once parses again")
    }
}

impl Crs {
    pub fn parse(definition: &str) -> Result<Self> {
        let trimmed = definition.trim();
        if trimmed.is_empty() {
            return Err(FormatError::Crs {
                crs: definition.into(),
                message: "empty CRS definition".into(),
            });
        }
        let mut srs = SpatialRef::from_definition(trimmed).map_err(|e| FormatError::Crs {
            crs: trimmed.chars().take(80).collect(),
            message: format!("not a CRS GDAL/PROJ knows ({e})"),
        })?;
        srs.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
        Ok(Self {
            definition: trimmed.to_string(),
            srs,
        })
    }

    pub fn from_epsg(code: u32) -> Result<Self> {
        Self::parse(&format!("EPSG:{code}"))
    }

    pub fn definition(&self) -> &str {
        &self.definition
    }

    pub fn spatial_ref(&self) -> &SpatialRef {
        &self.srs
    }

    /// `EPSG:n` when the CRS has an EPSG code, else its name.
    pub fn label(&self) -> String {
        match (self.srs.auth_name(), self.srs.auth_code()) {
            (Some(a), Ok(c)) => format!("{a}:{c}"),
            _ => self
                .srs
                .name()
                .unwrap_or_else(|| self.definition.chars().take(60).collect()),
        }
    }

    pub fn epsg(&self) -> Option<u32> {
        match (self.srs.auth_name().as_deref(), self.srs.auth_code()) {
            (Some("EPSG"), Ok(c)) if c > 0 => Some(c as u32),
            _ => None,
        }
    }

    pub fn to_wkt(&self) -> Result<String> {
        self.srs.to_wkt().map_err(|e| FormatError::Crs {
            crs: self.label(),
            message: format!("cannot export WKT ({e})"),
        })
    }

    pub fn is_geographic(&self) -> bool {
        self.srs.is_geographic()
    }

    pub fn is_projected(&self) -> bool {
        self.srs.is_projected()
    }

    /// Adjustment needs metric, conformal coordinates: refuse geographic CRSs and name a
    /// projected one that suits the data (the UTM zone of `lon_lat`, when known).
    pub fn require_projected(&self, lon_lat: Option<(f64, f64)>) -> Result<()> {
        if self.is_projected() {
            return Ok(());
        }
        let hint = match lon_lat {
            Some((lon, lat)) => {
                let zone = (((lon + 180.0) / 6.0).floor() as i32).clamp(0, 59) + 1;
                let epsg = if lat >= 0.0 {
                    32600 + zone
                } else {
                    32700 + zone
                };
                format!("use a projected CRS such as EPSG:{epsg} (WGS 84 / UTM zone {zone})")
            }
            None => "use a projected CRS in metres, e.g. the local UTM zone".into(),
        };
        Err(FormatError::Crs {
            crs: self.label(),
            message: format!(
                "is not projected; bundle adjustment needs metric coordinates: {hint}"
            ),
        })
    }
}

/// A coordinate transformation between two CRSs.
pub struct Transformer {
    source: String,
    target: String,
    ct: CoordTransform,
}

impl Transformer {
    pub fn new(source: &Crs, target: &Crs) -> Result<Self> {
        let ct = CoordTransform::new(source.spatial_ref(), target.spatial_ref()).map_err(|e| {
            FormatError::Crs {
                crs: format!("{} → {}", source.label(), target.label()),
                message: format!("no transformation ({e})"),
            }
        })?;
        Ok(Self {
            source: source.label(),
            target: target.label(),
            ct,
        })
    }

    /// Transforms coordinate arrays in place (x = easting/longitude, y = northing/latitude,
    /// z = height; pass an empty `z` for 2-D). Non-finite input is refused.
    pub fn transform(&self, x: &mut [f64], y: &mut [f64], z: &mut [f64]) -> Result<()> {
        let err = |message: String| FormatError::Crs {
            crs: format!("{} → {}", self.source, self.target),
            message,
        };
        if x.len() != y.len() || (!z.is_empty() && z.len() != x.len()) {
            return Err(err(format!(
                "coordinate arrays differ in length (x {}, y {}, z {})",
                x.len(),
                y.len(),
                z.len()
            )));
        }
        if let Some(i) = (0..x.len()).find(|&i| {
            !x[i].is_finite() || !y[i].is_finite() || z.get(i).is_some_and(|v| !v.is_finite())
        }) {
            return Err(err(format!("coordinate {i} is not finite")));
        }
        if x.is_empty() {
            return Ok(());
        }
        self.ct
            .transform_coords(x, y, z)
            .map_err(|e| err(format!("transformation failed ({e})")))
    }

    /// Transforms one point.
    pub fn transform_point(&self, p: [f64; 3]) -> Result<[f64; 3]> {
        let (mut x, mut y, mut z) = ([p[0]], [p[1]], [p[2]]);
        self.transform(&mut x, &mut y, &mut z)?;
        Ok([x[0], y[0], z[0]])
    }
}
