//! Project files: the documented example loads; mistakes fail at once naming the key.

use cloudcontrol::pipeline::project::Project;
use std::path::Path;

/// The project tree of formats/project/example.toml with empty input files; the text of
/// the example (its output is `out`).
pub(crate) fn example_tree(dir: &Path) -> String {
    for d in [
        "lidar",
        "epochs/reference/images",
        "epochs/digital/images",
        "epochs/film/images",
    ] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    for f in [
        "checkpoints.csv",
        "checkpoint_images.csv",
        "epochs/reference/camera.json",
        "epochs/reference/pos.csv",
        "epochs/digital/camera.json",
        "epochs/digital/pos.csv",
        "epochs/film/camera.json",
        "epochs/film/strips.csv",
    ] {
        std::fs::write(dir.join(f), "").unwrap();
    }
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("formats/project/example.toml"),
    )
    .unwrap()
}

fn load(dir: &Path, text: &str) -> Result<Project, String> {
    let path = dir.join("project.toml");
    std::fs::write(&path, text).unwrap();
    Project::load(&path).map_err(|e| e.to_string())
}

#[test]
fn documented_example_loads_with_paths_resolved() {
    let dir = tempfile::tempdir().unwrap();
    let text = example_tree(dir.path());
    let p = load(dir.path(), &text).unwrap();
    assert_eq!(p.archive.len(), 2);
    assert_eq!(
        p.archive[1].strips.as_deref(),
        Some(dir.path().join("epochs/film/strips.csv").as_path())
    );
    assert_eq!(p.output, dir.path().join("out"));
    assert_eq!(p.thresholds.reject_k, 2.5);
    // Film scan pixel size: given in µm, or in dpi (converted), or absent.
    assert_eq!(p.archive[1].scan_pixel_um, Some(21.0));
    assert_eq!(p.archive[1].scan_pixel_mm(), Some(0.021));
    assert_eq!(p.archive[0].scan_pixel_mm(), None);
    let dpi = load(
        dir.path(),
        &text.replace("scan_pixel_um = 21.0", "scan_dpi = 1270"),
    )
    .unwrap();
    assert!((dpi.archive[1].scan_pixel_mm().unwrap() - 0.02).abs() < 1e-15);
    // The fiducial-frame pixel of the film products: the mean scan pixel unless given.
    assert_eq!(p.outputs.film_pixel_um, None);
    let given = load(
        dir.path(),
        &text.replace("# film_pixel_um = 21.0", "film_pixel_um = 21.0"),
    )
    .unwrap();
    assert_eq!(given.outputs.film_pixel_um, Some(21.0));
    assert_eq!(
        p.control.checkpoint_images.as_deref(),
        Some(dir.path().join("checkpoint_images.csv").as_path())
    );
}

/// `Project::without_surfaces` (bench accuracy --no-surfaces, the orientation tests):
/// the surfaces and changes off, an orthophoto on the epoch's DSM back on the control's
/// ground, everything else the project as it was; a project without `[outputs]` gains
/// one.
#[test]
fn without_surfaces_turns_off_the_surfaces_alone() {
    use cloudcontrol::pipeline::project::OrthoSurface;
    let dir = tempfile::tempdir().unwrap();
    let text = example_tree(dir.path());
    let on = text.replace("ortho_surface = \"control\"", "ortho_surface = \"dsm\"");
    let a = load(dir.path(), &on).unwrap();
    assert!(a.outputs.dsm && a.outputs.change && a.outputs.ortho_surface == OrthoSurface::Dsm);
    let path = dir.path().join("project.toml");
    let off = Project::without_surfaces(&path).unwrap();
    assert_eq!(
        std::fs::read_to_string(&path).unwrap(),
        on,
        "the file is not touched"
    );
    let b = load(dir.path(), &off).unwrap();
    assert!(!b.outputs.dsm && !b.outputs.change);
    assert_eq!(b.outputs.ortho_surface, OrthoSurface::Control);
    // The same project but for its outputs (and the text's digest).
    let mut back = b.clone();
    back.outputs = a.outputs.clone();
    back.file_sha256 = a.file_sha256.clone();
    assert_eq!(back, a);
    // Without an [outputs] table.
    let bare = &text[..text.find("[outputs]").unwrap()];
    let c = load(dir.path(), bare).unwrap();
    let d = load(dir.path(), &Project::without_surfaces(&path).unwrap()).unwrap();
    assert!(!d.outputs.dsm && !d.outputs.change);
    let mut back = d.clone();
    back.outputs = c.outputs.clone();
    back.file_sha256 = c.file_sha256.clone();
    assert_eq!(back, c);
    assert!(matches!(
        Project::without_surfaces(&dir.path().join("missing.toml")),
        Err(cloudcontrol::pipeline::project::ProjectError::Io { .. })
    ));
}

#[test]
fn mistakes_fail_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let text = example_tree(dir.path());
    let cases: Vec<(String, &str)> = vec![
        (
            text.replace("reject_k = 2.5", "reject_k = 2.5\nrejekt = 2"),
            "rejekt",
        ),
        (text.replace("date = \"2010-08\"\n", ""), "date"),
        (
            text.replace("epochs/digital/pos.csv", "epochs/digital/nowhere.csv"),
            "archive[0].pos",
        ),
        (
            text.replace(
                "lidar = [\"lidar\"]",
                "lidar = [\"lidar\", \"missing.laz\"]",
            ),
            "control.lidar[1]",
        ),
        (
            text.replace("strips = \"epochs/film/strips.csv\"", ""),
            "archive[1].pos",
        ),
        (
            text.replace(
                "strips = \"epochs/film/strips.csv\"",
                "strips = \"epochs/film/strips.csv\"\npos = \"epochs/digital/pos.csv\"",
            ),
            "either pos or strips",
        ),
        (
            text.replace("date = \"1985\"", "date = \"2012\""),
            "archive[1].date",
        ),
        (text.replace("date = \"1985\"", "date = \"85\""), "ISO 8601"),
        (
            text.replace("crs = \"EPSG:4547\"", "crs = \"EPSG:4326\""),
            "crs",
        ),
        (
            text.replace("crs = \"EPSG:4547\"", "crs = \"EPSG:2994\""),
            "key `crs`: coordinate reference system \"NAD83(HARN) / Oregon GIC Lambert (ft)\": has horizontal unit foot",
        ),
        (
            text.replace("scan_pixel_um = 21.0", "scan_pixel_um = 0.021"),
            "key `archive[1].scan_pixel_um`: scan pixel size 0.021 µm is not a plausible",
        ),
        (
            text.replace("scan_pixel_um = 21.0", "scan_pixel_um = nan"),
            "archive[1].scan_pixel_um",
        ),
        (
            text.replace("scan_pixel_um = 21.0", "scan_dpi = 12"),
            "key `archive[1].scan_dpi`: 12 dpi: scan pixel size 2116.6",
        ),
        (
            text.replace("scan_pixel_um = 21.0", "scan_pixel_um = 21.0\nscan_dpi = 1200"),
            "either scan_pixel_um or scan_dpi",
        ),
        (
            text.replace("control_interval_px = 250", "control_interval_px = 2500"),
            "control_interval_px",
        ),
        (
            text.replace("ortho_gsd_factor = 1.0", "ortho_gsd_factor = 1.0\nfilm_pixel_um = 0.021"),
            "key `outputs.film_pixel_um`: scan pixel size 0.021 µm is not a plausible",
        ),
        (
            text.replace("name = \"film-1985\"", "name = \"digital-2010\""),
            "used twice",
        ),
    ];
    for (bad, needle) in cases {
        let e = load(dir.path(), &bad).unwrap_err();
        assert!(e.contains(needle), "error {e:?} should name {needle:?}");
        assert!(e.contains("project.toml"), "error names the file: {e}");
    }
}
