//! The workflow: the project file, restartable stages, the accuracy report, and the
//! `demo` that runs on built-in data.

pub mod bench;
pub mod change;
pub mod demo;
pub mod epoch_files;
pub mod film_frames;
pub(crate) mod ground;
pub mod partial;
pub mod products;
pub mod project;
pub mod report;
pub mod run;
pub mod stages;
pub(crate) mod surface;
pub mod tasks;
pub mod tie_statistics;
pub mod validate;
