//! `include/nlsim.h` is what cbindgen generates from `src/lib.rs` today. Run with
//! `NLSIM_BLESS=1` to rewrite it after changing the ABI.

use std::path::Path;

#[test]
fn the_header_in_the_repository_is_current() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_crate(dir)
        .with_config(config)
        .generate()
        .expect("cbindgen parses src/lib.rs")
        .write(&mut generated);
    let generated = String::from_utf8(generated).expect("the header is UTF-8");
    let path = dir.join("include/nlsim.h");
    if std::env::var_os("NLSIM_BLESS").is_some() {
        std::fs::write(&path, &generated).expect("write include/nlsim.h");
    }
    let current = std::fs::read_to_string(&path).unwrap_or_default();
    if current != generated {
        let line = current
            .lines()
            .zip(generated.lines())
            .position(|(a, b)| a != b)
            .map_or_else(
                || current.lines().count().min(generated.lines().count()) + 1,
                |i| i + 1,
            );
        panic!(
            "capi/include/nlsim.h differs from the header generated from capi/src/lib.rs \
             (first at line {line}); regenerate it with \
             `NLSIM_BLESS=1 cargo test -p nlsim-capi --test header` and commit it"
        );
    }
}
