//! No code: this crate only unifies the third-party crates' features across the workspace's
//! builds (see its Cargo.toml and `.config/hakari.toml`), so that the FMUs' release build and
//! the release test build share their compiled dependencies.
