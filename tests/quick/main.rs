//! The integration tests that take seconds, one module per former test file, in one
//! binary: each test binary links the whole library, and 40 of them cost CI more to build
//! than to run. The long end-to-end tests (whole workflows, accuracy over seeds) keep
//! their own binaries, so that they do not run beside each other.

#[path = "../common/mod.rs"]
mod common;
#[path = "../lidar_synth/mod.rs"]
mod lidar_synth;

mod adjust_block;
mod adjust_calib_lidar;
mod adjust_cli;
mod adjust_errors;
mod adjust_kite;
mod adjust_rejection;
mod check_inputs;
mod control_archive_cli;
mod control_cloud;
mod control_dcp;
mod control_dcp_cli;
mod control_orient;
mod control_ortho_source;
mod dense_epoch;
mod ffi;
mod ffi_handles;
mod formats_blocks_exchange;
mod formats_cameras;
mod formats_cli;
mod formats_colmap;
mod formats_control_points;
mod formats_crs;
mod formats_gdal;
mod formats_odm_gcp;
mod formats_ortho;
mod formats_readers;
mod formats_workflow;
mod geometry;
mod hostile_files;
mod hostile_inputs;
mod hostile_memory;
mod hostile_outputs;
mod hostile_packages;
mod hostile_references;
mod hostile_status;
mod leftovers;
mod lidar_clean_eval;
mod lidar_cli;
mod lidar_crs;
mod lidar_dem;
mod lidar_icp;
mod lidar_ingest;
mod matching_cli;
mod matching_core;
mod matching_fiducial;
mod matching_ties;
mod pipeline_project;
mod pipeline_report;
mod restart_fingerprint;
mod synth;
mod tie_statistics;
