// Cargo resolves a crate's build-dependencies only when it has a build script: this empty one
// lets the [build-dependencies] section unify the proc-macros' features (syn's among them).
fn main() {}
