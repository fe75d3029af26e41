//! The workflow. For now: the geometry self-check that `cloudcontrol demo` runs until the
//! synthetic block and the full five-step workflow land.

pub mod demo;
pub mod project;
pub mod report;
