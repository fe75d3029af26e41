//! include/cloudcontrol.h must be what cbindgen generates from the code now.
//! Regenerate with `CLOUDCONTROL_UPDATE_HEADER=1 cargo test --release --test header`.

use std::path::Path;

#[test]
fn committed_header_matches_cbindgen() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config =
        cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_crate(crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen generates the header");
    let mut generated = Vec::new();
    bindings.write(&mut generated);
    let path = crate_dir.join("include").join("cloudcontrol.h");
    if std::env::var_os("CLOUDCONTROL_UPDATE_HEADER").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &generated).unwrap();
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "include/cloudcontrol.h differs from the code; regenerate it with CLOUDCONTROL_UPDATE_HEADER=1 cargo test --release --test header"
    );
}
