//! Coordinate reference systems and transformations.
//!
//! We use GDAL's OSR (`OGRCoordinateTransformation`), which is PROJ underneath: GDAL is
//! loaded anyway for rasters ([`super::gdal`]), so this is one binding to one PROJ instead of two, and it
//! avoids pinning the `proj` crate to the old release that builds against Debian's PROJ.
//! Axis order is always the traditional GIS one (easting/longitude first).

use super::crs_input::{self, CrsSyntax};
use super::gdal::{CoordTransform, SpatialRef};
use super::{FormatError, Result};

/// A parsed CRS: from `EPSG:n`, WKT, PROJJSON or a PROJ string (never from a URL or a
/// file, see [`crs_input`]).
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
        // Each syntax goes to its own importer: GDAL's catch-all `SetFromUserInput` would
        // also fetch URLs and read files named by the string.
        let srs = match crs_input::classify(trimmed)? {
            CrsSyntax::Wkt => SpatialRef::from_wkt(trimmed),
            CrsSyntax::ProjString => SpatialRef::from_proj4(trimmed),
            // Vetted: `EPSG:n[+m]` and a PROJJSON CRS type take SetFromUserInput's
            // database and PROJJSON branches, which open nothing.
            CrsSyntax::Epsg | CrsSyntax::ProjJson => SpatialRef::from_user_input(trimmed),
        };
        let mut srs = srs.map_err(|e| FormatError::Crs {
            crs: crs_input::excerpt(trimmed),
            message: format!("not a CRS GDAL/PROJ knows ({e})"),
        })?;
        srs.set_traditional_gis_order();
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
            (Some(a), Some(c)) => format!("{a}:{c}"),
            _ => self
                .srs
                .name()
                .unwrap_or_else(|| self.definition.chars().take(60).collect()),
        }
    }

    pub fn epsg(&self) -> Option<u32> {
        match (self.srs.auth_name().as_deref(), self.srs.auth_code()) {
            (Some("EPSG"), Some(c)) if c > 0 => Some(c as u32),
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

    /// Adjustment needs metric, conformal coordinates: the same rule as
    /// [`Crs::require_metric_projected`] (kept under this name for its callers).
    pub fn require_projected(&self, lon_lat: Option<(f64, f64)>) -> Result<()> {
        self.require_metric_projected(lon_lat)
    }

    /// The one rule for every CRS cloudcontrol computes in (project, LiDAR tiles, blocks):
    /// the horizontal part is projected and in metres, and a vertical part, if any, is in
    /// metres. A geographic CRS is refused naming a projected one that suits the data (the
    /// UTM zone of `lon_lat`, when known); a unit other than the metre is refused naming
    /// the unit (heights and distances in feet would be silently wrong by 3.28×).
    pub fn require_metric_projected(&self, lon_lat: Option<(f64, f64)>) -> Result<()> {
        let horizontal = self.horizontal()?;
        if !horizontal.is_projected() {
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
            let what = if horizontal.spatial_ref().is_geocentric() {
                "is geocentric, not projected"
            } else {
                "is not projected"
            };
            return Err(FormatError::Crs {
                crs: self.label(),
                message: format!(
                    "{what}; cloudcontrol computes in projected metric coordinates: {hint}"
                ),
            });
        }
        let units = [
            ("horizontal", Some(horizontal.horizontal_unit()?)),
            ("vertical", self.vertical_unit()?),
        ];
        for (axis, unit) in units {
            if let Some(u) = unit.filter(|u| !u.is_metre()) {
                return Err(FormatError::Crs {
                    crs: self.name(),
                    message: format!(
                        "has {axis} unit {} ({} m); cloudcontrol works in metres: reproject \
                         the data to a metric CRS (e.g. `pdal translate in.laz out.laz \
                         reprojection --filters.reprojection.out_srs=EPSG:<metric CRS>`) or \
                         give a metric CRS",
                        u.name, u.metres
                    ),
                });
            }
        }
        Ok(())
    }

    /// The CRS name (GDAL's), else its label.
    pub fn name(&self) -> String {
        self.srs.name().unwrap_or_else(|| self.label())
    }

    pub fn is_compound(&self) -> bool {
        self.srs.is_compound()
    }

    /// Horizontal and vertical components (PROJJSON) of a compound CRS, else the CRS
    /// alone; a bound CRS (a WKT1 `TOWGS84` hint) is unwrapped to its source, as the
    /// datum-shift hint is not part of the CRS's identity. The flag tells whether the CRS
    /// was plain (neither compound nor bound).
    fn parts(&self) -> Result<(serde_json::Value, Option<serde_json::Value>, bool)> {
        let err = |message: String| FormatError::Crs {
            crs: self.label(),
            message,
        };
        let text = self
            .srs
            .to_projjson()
            .map_err(|e| err(format!("cannot export PROJJSON ({e})")))?;
        let mut v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| err(format!("GDAL wrote PROJJSON that does not parse ({e})")))?;
        let mut plain = true;
        let unbind = |v: &mut serde_json::Value, plain: &mut bool| {
            while v["type"] == "BoundCRS" {
                *v = v["source_crs"].take();
                *plain = false;
            }
        };
        unbind(&mut v, &mut plain);
        if v["type"] != "CompoundCRS" {
            return Ok((v, None, plain));
        }
        let mut parts = match v["components"].take() {
            serde_json::Value::Array(a) if !a.is_empty() => a,
            _ => return Err(err("compound CRS without components".into())),
        };
        let mut h = parts.remove(0);
        unbind(&mut h, &mut plain);
        Ok((h, parts.into_iter().next(), false))
    }

    fn from_projjson(v: &serde_json::Value) -> Result<Self> {
        Self::parse(&v.to_string())
    }

    /// The horizontal part: the first component of a compound CRS (projected + vertical),
    /// else the CRS itself (without a `TOWGS84` hint).
    pub fn horizontal(&self) -> Result<Crs> {
        match self.parts()? {
            (_, _, true) => Ok(self.clone()),
            (h, _, false) => Self::from_projjson(&h),
        }
    }

    /// The vertical part of a compound CRS.
    pub fn vertical(&self) -> Result<Option<Crs>> {
        if !self.is_compound() {
            return Ok(None);
        }
        self.parts()?
            .1
            .as_ref()
            .map(Self::from_projjson)
            .transpose()
    }

    /// Whether the horizontal parts are the same CRS (a compound CRS matches its
    /// horizontal CRS alone, whatever its vertical part).
    pub fn same_horizontal(&self, other: &Crs) -> Result<bool> {
        Ok(self.horizontal()?.spatial_ref() == other.horizontal()?.spatial_ref())
    }

    /// Unit of the horizontal axes (of the horizontal part of a compound CRS); for a
    /// geographic CRS the angular unit with its size in radians.
    pub fn horizontal_unit(&self) -> Result<LinearUnit> {
        let h = self.horizontal()?;
        let srs = h.spatial_ref();
        Ok(if srs.is_geographic() {
            LinearUnit {
                name: srs.angular_units().1.unwrap_or_else(|| "degree".into()),
                metres: srs.angular_units().0,
            }
        } else {
            LinearUnit {
                name: srs.linear_units().1.unwrap_or_else(|| "metre".into()),
                metres: srs.linear_units().0,
            }
        })
    }

    /// Unit of the vertical axis of a compound CRS.
    pub fn vertical_unit(&self) -> Result<Option<LinearUnit>> {
        if !self.is_compound() {
            return Ok(None);
        }
        let Some(v) = self.parts()?.1 else {
            return Ok(None);
        };
        let unit = &v["coordinate_system"]["axis"][0]["unit"];
        Ok(Some(match unit {
            serde_json::Value::String(name) if name == "metre" => LinearUnit::metre(),
            serde_json::Value::Object(o) => LinearUnit {
                name: o
                    .get("name")
                    .and_then(|n| n.as_str())
                    .unwrap_or("unnamed unit")
                    .to_string(),
                metres: o
                    .get("conversion_factor")
                    .and_then(|f| f.as_f64())
                    .unwrap_or(f64::NAN),
            },
            // PROJJSON omits the unit of a vertical axis in metres.
            serde_json::Value::Null => LinearUnit::metre(),
            other => LinearUnit {
                name: other.to_string(),
                metres: f64::NAN,
            },
        }))
    }

    /// The same CRS with its horizontal and/or vertical axes in other units: what a
    /// GeoTIFF key directory means by `ProjLinearUnitsGeoKey` / `VerticalUnitsGeoKey`
    /// next to an EPSG code in metres. Without a vertical part, a vertical unit adds one
    /// (datum unknown), so that the unit is not lost.
    pub fn with_units(
        &self,
        horizontal: Option<&LinearUnit>,
        vertical: Option<&LinearUnit>,
    ) -> Result<Crs> {
        if horizontal.is_none() && vertical.is_none() {
            return Ok(self.clone());
        }
        let unit_json = |u: &LinearUnit| serde_json::json!({"type": "LinearUnit", "name": u.name, "conversion_factor": u.metres});
        let set_unit = |part: &mut serde_json::Value, u: &LinearUnit| {
            if let Some(axes) = part["coordinate_system"]["axis"].as_array_mut() {
                for a in axes {
                    a["unit"] = unit_json(u);
                }
            }
            // No longer the registered CRS: keep its name, drop its code.
            if let Some(o) = part.as_object_mut() {
                o.remove("id");
                let name = o.get("name").and_then(|n| n.as_str()).unwrap_or("unnamed");
                let name = format!("{name} (axes in {})", u.name);
                o.insert("name".into(), name.into());
            }
        };
        let (mut h, v, _) = self.parts()?;
        if let Some(u) = horizontal {
            set_unit(&mut h, u);
        }
        let v = match (v, vertical) {
            (Some(mut v), Some(u)) => {
                set_unit(&mut v, u);
                Some(v)
            }
            (None, Some(u)) => Some(serde_json::json!({
                "type": "VerticalCRS",
                "name": format!("unknown height ({})", u.name),
                "datum": {"type": "VerticalReferenceFrame", "name": "unknown"},
                "coordinate_system": {"subtype": "vertical", "axis": [{
                    "name": "Gravity-related height", "abbreviation": "H",
                    "direction": "up", "unit": unit_json(u)}]},
            })),
            (v, None) => v,
        };
        let crs = match v {
            None => h,
            Some(v) => serde_json::json!({
                "type": "CompoundCRS",
                "name": format!(
                    "{} + {}",
                    h["name"].as_str().unwrap_or("unnamed"),
                    v["name"].as_str().unwrap_or("unnamed")
                ),
                "components": [h, v],
            }),
        };
        Self::from_projjson(&crs)
    }
}

/// A unit of length, with its size in metres (for an angular unit: in radians).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearUnit {
    pub name: String,
    pub metres: f64,
}

impl LinearUnit {
    pub fn metre() -> Self {
        Self {
            name: "metre".into(),
            metres: 1.0,
        }
    }

    pub fn is_metre(&self) -> bool {
        (self.metres - 1.0).abs() < 1e-12
    }

    /// A unit by its EPSG code (the values of GeoTIFF's unit keys): the metre and the
    /// feet that LiDAR deliveries use; None for other codes.
    pub fn from_epsg(code: u16) -> Option<Self> {
        let (name, metres) = match code {
            9001 => ("metre", 1.0),
            9002 => ("foot", 0.3048),
            9003 => ("US survey foot", 1200.0 / 3937.0),
            9005 => ("Clarke's foot", 0.3047972654),
            9036 => ("kilometre", 1000.0),
            _ => return None,
        };
        Some(Self {
            name: name.into(),
            metres,
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
