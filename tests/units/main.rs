//! Tests of single modules, kept out of the library so that `cargo test` does not compile
//! the whole library a second time with `cfg(test)` (on CI's 2 cores that build took as
//! long as the library's own).

mod adjust_chi2;
mod adjust_datum;
mod adjust_rays;
mod adjust_resection;
mod adjust_selinv;
mod adjust_support;
mod adjust_tie_prior;
mod cache;
mod change;
mod control_checkpoints;
mod control_chips;
mod control_epoch;
mod control_orient_order;
mod control_photo;
mod control_predict;
mod control_rounds;
mod control_strips;
mod dense_fusion;
mod dense_rectify;
mod dense_scene;
mod dense_sgm;
mod dense_synthetic;
mod estimators;
mod estimators_similarity2;
mod estimators_similarity3;
mod formats_adjust_report;
mod formats_crs_input;
mod formats_csv;
mod formats_ortho_tiles;
mod formats_paths;
mod formats_pos;
mod formats_tiff_window;
mod geometry_serde_matrix;
mod lidar_grid_index;
mod lidar_las;
mod matching_fiducial_frame_image;
mod matching_pyramid;
mod matching_smooth;
mod pipeline_bench;
mod pipeline_run;
mod pipeline_stages;
mod synth_noise;
mod synth_scene;
mod synth_truth;
