//! Compiles the variadic FMI 2.0 logger (C varargs cannot be defined in stable Rust).

fn main() {
    println!("cargo:rerun-if-changed=csrc/logger.c");
    cc::Build::new()
        .file("csrc/logger.c")
        .warnings(true)
        .compile("m1cs_cosim_logger");
}
