//! The workflow through the C ABI: run a project file and get its report as JSON (a
//! string owned by the library, released with `ccp_string_free`).

use super::{guard, CcpStatus, FfiError};
use crate::pipeline::project::{Project, ProjectError};
use crate::pipeline::run::{run_project, RunError};
use std::ffi::{c_char, CStr, CString};
use std::path::PathBuf;

impl From<RunError> for FfiError {
    fn from(e: RunError) -> Self {
        let status = match &e {
            RunError::Project(ProjectError::Io { .. }) => CcpStatus::Io,
            RunError::Project(_) => CcpStatus::InvalidArgument,
            RunError::Stage(_) | RunError::Stopped(_) => CcpStatus::Numeric,
        };
        FfiError::new(status, e.to_string())
    }
}

/// Runs the project file `project_path` (TOML, formats/project/) — restartable: finished
/// stages whose inputs did not change are skipped — and returns in `*out_json` a
/// NUL-terminated JSON object `{"output", "ran", "skipped", "products", "report"}`, owned by
/// the library: release it with `ccp_string_free`. An invalid project file fails before
/// any work with `CCP_STATUS_INVALID_ARGUMENT` and a message naming the key.
#[no_mangle]
pub unsafe extern "C" fn ccp_project_run(
    project_path: *const c_char,
    out_json: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        if out_json.is_null() || project_path.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "project_path or out_json is a null pointer",
            ));
        }
        *out_json = std::ptr::null_mut();
        let path = CStr::from_ptr(project_path)
            .to_str()
            .map_err(|_| FfiError::invalid("project_path is not UTF-8"))?;
        let project = Project::load(&PathBuf::from(path)).map_err(RunError::from)?;
        let s = run_project(&project, &mut |_| {}, None)?;
        let c = CString::new(s.to_json().to_string())
            .map_err(|_| FfiError::invalid("report JSON holds a NUL byte"))?;
        *out_json = super::handles::hand_out_string(c);
        Ok(())
    })
}
