//! `cloudcontrol lidar ...` and `cloudcontrol icp`: argument parsing and printing only.

use clap::{Args, Subcommand, ValueEnum};
use cloudcontrol::formats::raster::{write_dem, GeoTiffOptions};
use cloudcontrol::formats::write_bytes_atomically;
use cloudcontrol::geometry::Similarity;
use cloudcontrol::lidar::clean::{clean_tiles, CleanOptions, OffsetModel};
use cloudcontrol::lidar::dem::grid_dem_tiles;
use cloudcontrol::lidar::eval::evaluate_checkpoints_store;
use cloudcontrol::lidar::las::read_points;
use cloudcontrol::lidar::points_io::read_xyz;
use cloudcontrol::lidar::{
    grid_dem, icp_point_to_plane, Bbox, Catalogue, CheckpointOptions, DemMethod, DemOptions,
    IcpModel, IcpOptions, LasStream, OutlierOptions, PlaneIndex, PlaneOptions, ScanOptions,
    StripOffsetOptions, TileStore,
};
use nalgebra::Vector3;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Where the LiDAR comes from: LAS/LAZ files, folders of them, or one catalogue JSON.
#[derive(Args, Debug, Clone)]
pub struct Source {
    /// LAS/LAZ files, folders holding them, or a catalogue .json.
    #[arg(long = "lidar", required = true, num_args = 1..)]
    pub lidar: Vec<PathBuf>,
    /// CRS for files without one (e.g. EPSG:32650).
    #[arg(long)]
    pub crs: Option<String>,
    /// Bound on the LiDAR points held in memory at once (tiles are loaded on demand, LRU).
    #[arg(long, default_value_t = 50_000_000)]
    pub max_points: u64,
}

impl Source {
    fn catalogue(&self) -> Result<Catalogue, String> {
        Catalogue::open(
            &self.lidar,
            &ScanOptions {
                assume_crs: self.crs.clone(),
            },
        )
        .map_err(|e| e.to_string())
    }
}

#[derive(Subcommand, Debug)]
pub enum LidarCommand {
    /// Header facts of LAS/LAZ files (version, format, count, bounds, CRS) without reading points.
    ///
    /// Example: cloudcontrol lidar info tiles/*.las
    Info {
        /// LAS/LAZ files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Scan tiles into a source catalogue (bounds, counts, density, classes, strips,
    /// GPS time and dates, CRS); all tiles must share one CRS.
    ///
    /// Example: cloudcontrol lidar catalogue tiles/ --out catalogue.json
    #[command(alias = "catalog")]
    Catalogue {
        /// LAS/LAZ files or folders.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Catalogue JSON to write.
        #[arg(long)]
        out: Option<PathBuf>,
        /// CRS for files without one (e.g. EPSG:32650).
        #[arg(long)]
        crs: Option<String>,
    },
    /// Compare LiDAR ground heights with surveyed checkpoints (CSV id,X,Y,Z).
    ///
    /// dz = LiDAR − checkpoint, from a local plane of ground points around each checkpoint.
    ///
    /// Example: cloudcontrol lidar eval --lidar tiles/ --checkpoints gcp.csv --out eval.json
    Eval {
        #[command(flatten)]
        source: Source,
        /// CSV with id,X,Y,Z per line (header line optional).
        #[arg(long)]
        checkpoints: PathBuf,
        /// Ground class(es); repeat for several. Default 2 (ASPRS ground).
        #[arg(long = "ground-class", default_values_t = vec![2u8])]
        ground_class: Vec<u8>,
        /// Use every point, not only the ground class.
        #[arg(long)]
        all_classes: bool,
        /// Search radius (m) of the local plane.
        #[arg(long, default_value_t = 3.0)]
        radius: f64,
        /// Report JSON to write.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Remove isolated noise points and per-strip (point source id) offsets; writes
    /// cleaned copies of the tiles and reports what it found.
    ///
    /// Example: cloudcontrol lidar clean --lidar tiles/ --out-dir clean/ --report clean.json
    Clean {
        #[command(flatten)]
        source: Source,
        /// Folder for the cleaned tiles (same names and formats as the inputs).
        #[arg(long)]
        out_dir: PathBuf,
        /// Report JSON to write.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Neighbours of the statistical outlier filter.
        #[arg(long, default_value_t = 8)]
        k: usize,
        /// Noise threshold: mean + n·σ of the neighbour distances.
        #[arg(long, default_value_t = 3.0)]
        n_sigma: f64,
        /// Skip the noise filter.
        #[arg(long)]
        no_filter: bool,
        /// Skip the strip offsets.
        #[arg(long)]
        no_strips: bool,
        /// Strip offset model: auto takes a 3-D shift per strip where the overlapping
        /// planes (roofs, slopes) determine it to 1 cm in plan, a height offset alone
        /// elsewhere; the report says which it took and why.
        #[arg(long, value_enum, default_value_t = OffsetArg::Vertical)]
        model: OffsetArg,
        /// Strip held fixed (point source id); default: the offsets have zero mean over the strips.
        #[arg(long)]
        reference: Option<u16>,
        /// Drop noise points instead of classifying them 7 (noise).
        #[arg(long)]
        drop_noise: bool,
    },
    /// Grid ground points into a DEM GeoTIFF (float32, CRS, nodata −9999).
    ///
    /// Example: cloudcontrol lidar dem --lidar tiles/ --cell 1 --out dem.tif
    Dem {
        #[command(flatten)]
        source: Source,
        /// GeoTIFF to write.
        #[arg(long)]
        out: PathBuf,
        /// Cell size (m).
        #[arg(long, default_value_t = 1.0)]
        cell: f64,
        /// Height of a cell: the mean of its ground points, or inverse-distance weighted
        /// (idw, with --power).
        #[arg(long, value_enum, default_value_t = DemArg::Mean)]
        method: DemArg,
        /// IDW power.
        #[arg(long, default_value_t = 2.0)]
        power: f64,
        /// Fill holes up to this many cells from data.
        #[arg(long, default_value_t = 5)]
        fill: usize,
        /// Ground class(es). Default 2.
        #[arg(long = "ground-class", default_values_t = vec![2u8])]
        ground_class: Vec<u8>,
        /// Use every point, not only the ground class.
        #[arg(long)]
        all_classes: bool,
        /// Extent min_x,min_y,max_x,max_y (default: the catalogue bounds).
        #[arg(long, value_delimiter = ',', num_args = 4)]
        bbox: Option<Vec<f64>>,
    },
}

#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum OffsetArg {
    Auto,
    Vertical,
    Translation,
}

#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum DemArg {
    Mean,
    Idw,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
pub enum ModelArg {
    Similarity,
    Rigid,
}

/// Register points (photogrammetric tie points, another cloud) onto the LiDAR surface by
/// point-to-plane ICP; writes the 4×4 transform (source → LiDAR) with its statistics.
///
/// Example: cloudcontrol icp --source tie_points.csv --target tiles/ --out transform.json
///
/// Example: cloudcontrol --json icp --source tie_points.ply --target tiles/tile_499900_4399900.las tiles/tile_500000_4399900.las --rigid
#[derive(Args, Debug)]
pub struct IcpArgs {
    /// Source points: CSV/text (X,Y,Z), PLY or LAS/LAZ.
    #[arg(long)]
    pub source: PathBuf,
    /// LiDAR: LAS/LAZ files, folders, or a catalogue .json.
    #[arg(long, required = true, num_args = 1..)]
    pub target: Vec<PathBuf>,
    /// CRS for LiDAR files without one.
    #[arg(long)]
    pub crs: Option<String>,
    /// Transform estimated: similarity (7 parameters: scale, rotation, shift) or rigid
    /// (6: rotation, shift).
    #[arg(long, value_enum, default_value_t = ModelArg::Similarity)]
    pub model: ModelArg,
    /// Same as --model rigid.
    #[arg(long)]
    pub rigid: bool,
    /// Transform JSON to write.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Neighbours per plane fit.
    #[arg(long, default_value_t = 12)]
    pub k: usize,
    /// Largest coplanarity λmin/Σλ accepted as a plane.
    #[arg(long, default_value_t = 0.02)]
    pub max_coplanarity: f64,
    /// Initial distance gate (m): must cover the start error.
    #[arg(long, default_value_t = 30.0)]
    pub initial_gate: f64,
    /// Final gate floor (m), 3–5× the LiDAR noise.
    #[arg(long, default_value_t = 0.3)]
    pub min_gate: f64,
    /// Most ICP iterations.
    #[arg(long, default_value_t = 100)]
    pub max_iterations: usize,
    /// Bound on the LiDAR points loaded (the source's extent plus the gate).
    #[arg(long, default_value_t = 200_000_000)]
    pub max_points: u64,
}

fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

fn write_json(path: &Path, v: &serde_json::Value) -> Result<(), String> {
    let text = serde_json::to_string_pretty(v).map_err(|e| e.to_string())?;
    write_bytes_atomically(path, text.as_bytes()).map_err(|e| e.to_string())
}

/// The checkpoints of `lidar eval --checkpoints`: the control points CSV
/// (formats/control-points/: `id,x,y,z[,sigma_xy,sigma_z][,kind]`) read by the one reader
/// the pipeline reads its checkpoints with (`control_points::read_points`).
pub fn read_checkpoints(path: &Path) -> Result<Vec<(String, [f64; 3])>, String> {
    let points =
        cloudcontrol::formats::control_points::read_points(path).map_err(|e| e.to_string())?;
    if points.is_empty() {
        return Err(format!("{}: no checkpoint", path.display()));
    }
    Ok(points.into_iter().map(|p| (p.id, p.xyz)).collect())
}

fn classes(ground: &[u8], all: bool) -> Option<Vec<u8>> {
    (!all).then(|| ground.to_vec())
}

pub fn run_lidar(cmd: LidarCommand, json_out: bool, quiet: bool) -> Result<(), String> {
    match cmd {
        LidarCommand::Info { files } => {
            let mut infos = Vec::new();
            for f in &files {
                let s = LasStream::open(f).map_err(|e| e.to_string())?;
                infos.push(s.info().clone());
            }
            if json_out {
                outln!("{}", serde_json::to_string_pretty(&infos).unwrap());
            } else if !quiet {
                for i in &infos {
                    let b = i.header_bounds;
                    outln!(
                        "{}: LAS {} format {}{}, {} points, x {:.2}..{:.2} y {:.2}..{:.2} z {:.2}..{:.2}, CRS {}",
                        i.file.display(),
                        i.version,
                        i.point_format,
                        if i.compressed { " (LAZ)" } else { "" },
                        i.point_count,
                        b[0],
                        b[3],
                        b[1],
                        b[4],
                        b[2],
                        b[5],
                        i.crs_label.as_deref().unwrap_or("none")
                    );
                }
            }
        }
        LidarCommand::Catalogue { inputs, out, crs } => {
            let t = Instant::now();
            let cat = Catalogue::scan(&inputs, &ScanOptions { assume_crs: crs })
                .map_err(|e| e.to_string())?;
            if let Some(o) = &out {
                cat.save(o).map_err(|e| e.to_string())?;
            }
            if json_out {
                outln!("{}", cat.to_json());
            } else if !quiet {
                outln!(
                    "{} tiles, {} points, CRS {}, scanned in {:.2} s",
                    cat.tiles.len(),
                    cat.point_count,
                    cat.crs,
                    secs(t)
                );
                for tile in &cat.tiles {
                    outln!(
                        "  {}: {} points, {:.2} pts/m², classes {:?}, strips {:?}, dates {}",
                        tile.file.display(),
                        tile.point_count,
                        tile.density_pts_m2,
                        tile.classes,
                        tile.point_sources.keys().collect::<Vec<_>>(),
                        tile.acquisition_dates
                            .as_ref()
                            .map(|d| format!("{}..{}", d[0], d[1]))
                            .unwrap_or_else(|| "unknown".into())
                    );
                }
                if let Some(o) = &out {
                    outln!("catalogue written to {}", o.display());
                }
            }
        }
        LidarCommand::Eval {
            source,
            checkpoints,
            ground_class,
            all_classes,
            radius,
            out,
        } => {
            let cps = read_checkpoints(&checkpoints)?;
            let mut store = TileStore::new(source.catalogue()?, source.max_points);
            let opts = CheckpointOptions {
                radius,
                ..Default::default()
            };
            let cls = classes(&ground_class, all_classes);
            let rep = evaluate_checkpoints_store(&mut store, &cps, cls.as_deref(), &opts)
                .map_err(|e| e.to_string())?;
            let v = serde_json::to_value(&rep).unwrap();
            if let Some(o) = &out {
                write_json(o, &v)?;
            }
            if json_out {
                outln!("{}", serde_json::to_string_pretty(&v).unwrap());
            } else if !quiet {
                out!("{}", rep.to_text());
            }
        }
        LidarCommand::Clean {
            source,
            out_dir,
            report,
            k,
            n_sigma,
            no_filter,
            no_strips,
            model,
            reference,
            drop_noise,
        } => {
            let cat = source.catalogue()?;
            let opts = CleanOptions {
                outliers: (!no_filter).then_some(OutlierOptions { k, n_sigma }),
                strips: (!no_strips).then(|| StripOffsetOptions {
                    model: match model {
                        OffsetArg::Auto => OffsetModel::Auto,
                        OffsetArg::Vertical => OffsetModel::Vertical,
                        OffsetArg::Translation => OffsetModel::Translation,
                    },
                    reference,
                    ..Default::default()
                }),
                drop_noise,
                max_points_for_offsets: source.max_points.min(usize::MAX as u64) as usize,
                ..Default::default()
            };
            let rep = clean_tiles(&cat, &out_dir, &opts).map_err(|e| e.to_string())?;
            let v = serde_json::to_value(&rep).unwrap();
            if let Some(o) = &report {
                write_json(o, &v)?;
            }
            if json_out {
                outln!("{}", serde_json::to_string_pretty(&v).unwrap());
            } else if !quiet {
                if let Some(s) = &rep.strip_offsets {
                    let datum = match s.reference {
                        Some(r) => format!("strip {r} held"),
                        None => "zero mean over the strips".into(),
                    };
                    outln!(
                        "strip offsets ({:?} model, {datum}, σ0 {:.3} m):",
                        s.model,
                        s.sigma0_m
                    );
                    if let Some(why) = &s.vertical_because {
                        outln!("  height offsets alone: {why}");
                    }
                    for st in &s.strips {
                        outln!(
                            "  strip {:>5}: dx {:+.3} dy {:+.3} dz {:+.3} m (σ {:.3} {:.3} {:.3}), {} points",
                            st.source_id,
                            st.offset_m[0],
                            st.offset_m[1],
                            st.offset_m[2],
                            st.sigma_m[0],
                            st.sigma_m[1],
                            st.sigma_m[2],
                            st.points
                        );
                    }
                }
                for t in &rep.tiles {
                    outln!(
                        "  {} → {}: {} points, {} noise, {} written",
                        t.file.display(),
                        t.output.display(),
                        t.points,
                        t.noise,
                        t.written
                    );
                }
            }
        }
        LidarCommand::Dem {
            source,
            out,
            cell,
            method,
            power,
            fill,
            ground_class,
            all_classes,
            bbox,
        } => {
            let cat = source.catalogue()?;
            let crs = cat.crs().map_err(|e| e.to_string())?;
            let b = match bbox {
                Some(v) => Bbox::new(v[0], v[1], v[2], v[3]),
                None => Bbox::new(cat.bounds[0], cat.bounds[1], cat.bounds[3], cat.bounds[4]),
            };
            let cls = classes(&ground_class, all_classes);
            let mut opts = DemOptions {
                cell,
                method: DemMethod::Mean,
                max_fill_cells: fill,
                bbox: Some(b),
                ..Default::default()
            };
            // Mean: tiles are streamed into the grid (memory: the grid). IDW needs the
            // points of neighbouring cells, so the extent is loaded.
            let (dem, n_points) = match method {
                DemArg::Mean => {
                    grid_dem_tiles(&cat, &b, cls.as_deref(), &opts).map_err(|e| e.to_string())?
                }
                DemArg::Idw => {
                    opts.method = DemMethod::Idw { power };
                    let mut store = TileStore::new(cat, source.max_points);
                    let pts = store.query(&b, cls.as_deref()).map_err(|e| e.to_string())?;
                    let dem = grid_dem(&pts.xyz, &opts).map_err(|e| e.to_string())?;
                    (dem, pts.len() as u64)
                }
            };
            write_dem(&out, &dem, &crs, &GeoTiffOptions::default()).map_err(|e| e.to_string())?;
            let nodata = dem.data.iter().filter(|v| !v.is_finite()).count();
            let (z0, z1) = dem.z_range();
            let v = json!({
                "out": out, "width": dem.width, "height": dem.height, "cell_m": cell,
                "points": n_points, "nodata_cells": nodata, "z_min": z0, "z_max": z1, "crs": crs.label(),
            });
            if json_out {
                outln!("{}", serde_json::to_string_pretty(&v).unwrap());
            } else if !quiet {
                outln!(
                    "DEM {}×{} at {} m from {} points, z {:.2}..{:.2}, {} nodata cells → {}",
                    dem.width,
                    dem.height,
                    cell,
                    n_points,
                    z0,
                    z1,
                    nodata,
                    out.display()
                );
            }
        }
    }
    Ok(())
}

pub fn run_icp(a: IcpArgs, json_out: bool, quiet: bool) -> Result<(), String> {
    let t_all = Instant::now();
    let t = Instant::now();
    let src = read_xyz(&a.source).map_err(|e| e.to_string())?;
    let read_source_s = secs(t);
    let t = Instant::now();
    let cat = Catalogue::open(
        &a.target,
        &ScanOptions {
            assume_crs: a.crs.clone(),
        },
    )
    .map_err(|e| e.to_string())?;
    let bbox = Bbox::of_points(&src, a.initial_gate).expect("source is not empty");
    // Stream the tiles around the source, keeping only the coordinates inside the extent
    // (no tile cache: the index is the one copy of the points).
    let mut xyz: Vec<[f64; 3]> = Vec::new();
    for i in cat.tiles_in(&bbox) {
        let mut part = read_points(&cat.tiles[i].file, Some(bbox.as_array()), None)
            .map_err(|e| e.to_string())?;
        xyz.append(&mut part.xyz);
        if xyz.len() as u64 > a.max_points {
            return Err(format!(
                "more than --max-points {} LiDAR points around the source; raise it or split the source",
                a.max_points
            ));
        }
    }
    let read_lidar_s = secs(t);
    if xyz.is_empty() {
        return Err(format!(
            "no LiDAR point within {} m of the source points' extent (check the CRS of {})",
            a.initial_gate,
            a.source.display()
        ));
    }
    let t = Instant::now();
    let c = Bbox::of_points(&xyz, 0.0).expect("non-empty");
    let origin = Vector3::new(
        0.5 * (c.min_x + c.max_x),
        0.5 * (c.min_y + c.max_y),
        xyz[0][2],
    );
    // Move the coordinates into the index (local frame, in place).
    let n_lidar = xyz.len();
    let mut local = xyz;
    for p in local.iter_mut() {
        p[0] -= origin.x;
        p[1] -= origin.y;
        p[2] -= origin.z;
    }
    let index = PlaneIndex::from_local(
        local,
        origin,
        PlaneOptions {
            k: a.k,
            max_coplanarity: a.max_coplanarity,
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let index_s = secs(t);
    let model = if a.rigid || a.model == ModelArg::Rigid {
        IcpModel::Rigid
    } else {
        IcpModel::Similarity
    };
    let opts = IcpOptions {
        model,
        max_iterations: a.max_iterations,
        initial_gate: a.initial_gate,
        min_gate: a.min_gate,
        ..Default::default()
    };
    let t = Instant::now();
    let r = icp_point_to_plane(&index, &src, &Similarity::identity(), &opts)
        .map_err(|e| format!("ICP of {}: {e}", a.source.display()))?;
    let icp_s = secs(t);
    let m = r.matrix();
    let matrix: Vec<Vec<f64>> = (0..4)
        .map(|i| (0..4).map(|j| m[(i, j)]).collect())
        .collect();
    let sd: Vec<f64> = (0..7)
        .map(|i| r.covariance[(i, i)].max(0.0).sqrt())
        .collect();
    let v = json!({
        "matrix": matrix,
        "model": model,
        "scale": r.transform.scale,
        "translation": [r.transform.translation.x, r.transform.translation.y, r.transform.translation.z],
        "rmse_m": r.rmse_m,
        "sigma0_m": r.sigma0_m,
        "iterations": r.iterations.len(),
        "inliers": r.inliers,
        "converged": r.converged,
        "precision": {
            "rotation_rad": [sd[0], sd[1], sd[2]],
            "translation_m": [sd[3], sd[4], sd[5]],
            "scale": sd[6],
        },
        "source_points": src.len(),
        "lidar_points": n_lidar,
        "timing_s": {
            "read_source": read_source_s, "read_lidar": read_lidar_s, "index": index_s,
            "icp": icp_s, "total": secs(t_all),
        },
        "iteration_stats": r.iterations,
    });
    if let Some(o) = &a.out {
        write_json(o, &v)?;
    }
    if json_out {
        outln!("{}", serde_json::to_string_pretty(&v).unwrap());
    } else if !quiet {
        outln!(
            "ICP ({:?}) {} source points on {} LiDAR points: {} iterations{}, RMSE {:.3} m, {} inliers, scale {:.6}",
            model,
            src.len(),
            n_lidar,
            r.iterations.len(),
            if r.converged { "" } else { " (not converged)" },
            r.rmse_m,
            r.inliers,
            r.transform.scale
        );
        for row in &matrix {
            outln!(
                "  [{:>14.6} {:>14.6} {:>14.6} {:>16.4}]",
                row[0],
                row[1],
                row[2],
                row[3]
            );
        }
        if let Some(o) = &a.out {
            outln!("transform written to {}", o.display());
        }
    }
    Ok(())
}
