//! [`Layout::load`]: one name for a preset or a JSON file, as the command line's `--layout`.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests panic on failure by design

use m1::aperture::layout::{DEFAULT_LAYOUT, Layout, LayoutError};

#[test]
fn presets_by_name_in_any_case() {
    assert_eq!(Layout::load("TMT").unwrap().n_segments(), 492);
    assert_eq!(Layout::load(" keck ").unwrap().n_segments(), 36);
    assert_eq!(Layout::load(DEFAULT_LAYOUT).unwrap(), Layout::tmt());
    match Layout::load("nope") {
        Err(e @ LayoutError::UnknownPreset { .. }) => assert!(e.to_string().contains("nope")),
        other => panic!("expected UnknownPreset, got {other:?}"),
    }
}

#[test]
fn json_files_by_extension_in_any_case() {
    let dir = std::env::temp_dir().join(format!("m1-layout-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let keck = Layout::keck();
    for file in ["keck.json", "keck.JSON"] {
        let path = dir.join(file);
        keck.write_json_file(&path).unwrap();
        assert_eq!(
            Layout::load(path.to_str().unwrap()).unwrap(),
            keck,
            "{file}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
    match Layout::load("/nonexistent/dir/layout.json") {
        Err(e @ LayoutError::Io { .. }) => assert!(e.to_string().contains("layout.json")),
        other => panic!("expected Io error, got {other:?}"),
    }
}
