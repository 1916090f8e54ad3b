//! The on-disk cache serves the structure's modes and the wind's tables exactly as computed:
//! a second build from the cache equals the first bit for bit, a corrupt entry is rebuilt, and
//! other inputs make other entries.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::linalg::cache::Store;
use m1::loads::wind::{WindLoads, WindParams};
use m1::plant::structure::{CellModel, Flexibility, ModalModel, StructurePreset};

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("m1-cache-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn modes_from_the_cache_are_the_computed_modes() {
    let dir = scratch("modes");
    let store = Store::at(&dir);
    let layout = Layout::preset("keck").unwrap();
    let cell = CellModel::new(&layout, &StructurePreset::Tmt.params()).unwrap();
    let computed = cell.modes_in(&Store::off()).unwrap();
    let first = cell.modes_in(&store).unwrap();
    assert_eq!(store.entries().len(), 1, "the first build stores its modes");
    let cached = cell.modes_in(&store).unwrap();
    for m in [&first, &cached] {
        assert_eq!(bits(&m.frequencies), bits(&computed.frequencies));
        assert_eq!(bits(&m.phi_cell), bits(&computed.phi_cell));
        assert_eq!(bits(&m.phi_pier), bits(&computed.phi_pier));
        assert_eq!(m.k_pier.to_bits(), computed.k_pier.to_bits());
    }
    // The static correction comes with the cached modes too: same response to a load.
    let f: Vec<f64> = (0..computed.na).map(|k| (k as f64).cos()).collect();
    let respond = |m: &ModalModel| match &m.flexibility {
        Flexibility::FiniteElement(s) => {
            let (mut work, mut z) = (vec![0.0; s.ndof()], vec![0.0; m.na]);
            s.apply(&f, 0.1, &mut work, &mut z);
            z
        }
        _ => panic!("the built-in cell's static correction is its FE solve"),
    };
    assert_eq!(bits(&respond(&computed)), bits(&respond(&cached)));
    assert!(respond(&cached).iter().any(|z| *z != 0.0));
    // Another cell, another entry.
    let soft = CellModel::new(&layout, &StructurePreset::SoftCell.params()).unwrap();
    let other = soft.modes_in(&store).unwrap();
    assert_eq!(store.entries().len(), 2);
    assert_ne!(bits(&other.frequencies), bits(&computed.frequencies));
    // A corrupt entry is detected, rebuilt and stored again.
    for (path, _) in store.entries() {
        let mut bytes = std::fs::read(&path).unwrap();
        let at = bytes.len() / 3;
        bytes[at] ^= 0x10;
        std::fs::write(&path, bytes).unwrap();
    }
    let rebuilt = cell.modes_in(&store).unwrap();
    assert_eq!(bits(&rebuilt.frequencies), bits(&computed.frequencies));
    assert_eq!(bits(&rebuilt.phi_cell), bits(&computed.phi_cell));
    assert_eq!(bits(&rebuilt.phi_pier), bits(&computed.phi_pier));
    assert_eq!(
        bits(&cell.modes_in(&store).unwrap().phi_cell),
        bits(&computed.phi_cell)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn wind_tables_from_the_cache_are_the_synthesised_tables() {
    let dir = scratch("wind");
    let store = Store::at(&dir);
    let layout = Layout::preset("keck").unwrap();
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let mut params = WindParams::default();
    params.screen.samples = 256;
    params.screen.size = 64.0;
    let computed = WindLoads::new_in(&geometry, &params, &Store::off()).unwrap();
    let first = WindLoads::new_in(&geometry, &params, &store).unwrap();
    assert_eq!(store.entries().len(), 1);
    let cached = WindLoads::new_in(&geometry, &params, &store).unwrap();
    let na = layout.n_actuators();
    let (mut a, mut b, mut c) = (vec![0.0; na], vec![0.0; na], vec![0.0; na]);
    for k in 0..50 {
        let t = 0.137 * f64::from(k);
        computed.forces(t, &mut a).unwrap();
        first.forces(t, &mut b).unwrap();
        cached.forces(t, &mut c).unwrap();
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(bits(&a), bits(&c), "t = {t}");
    }
    assert!(a.iter().any(|x| *x != 0.0));
    assert_eq!(
        computed.expected_force_rms().to_bits(),
        cached.expected_force_rms().to_bits()
    );
    // Another seed, another entry; another speed shares the tables (the same entry).
    params.speed = 3.0;
    WindLoads::new_in(&geometry, &params, &store).unwrap();
    assert_eq!(store.entries().len(), 1);
    params.screen.seed = 2;
    WindLoads::new_in(&geometry, &params, &store).unwrap();
    assert_eq!(store.entries().len(), 2);
    let _ = std::fs::remove_dir_all(&dir);
}
