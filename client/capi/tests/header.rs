//! The committed C header `include/lightfarm.h` is exactly what cbindgen generates from this
//! crate with `cbindgen.toml`: a changed entry point, type or doc comment fails this test until
//! the header is refreshed with `LIGHTFARM_BLESS=1`.
//!
//! cbindgen runs through its library API on `src/lib.rs` (it follows the `mod` items), so no
//! build script and no `cargo metadata` call are involved.

use std::path::{Path, PathBuf};

const REFRESH: &str =
    "LIGHTFARM_BLESS=1 cargo test --release -p lightfarm-client-capi --test header";

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The header cbindgen generates now.
fn generate(dir: &Path) -> String {
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen parses the crate");
    let mut bytes = Vec::new();
    bindings.write(&mut bytes);
    String::from_utf8(bytes).expect("cbindgen writes UTF-8")
}

#[test]
fn committed_header_matches_the_generated_one() {
    let dir = crate_dir();
    let path = dir.join("include/lightfarm.h");
    let generated = generate(&dir);
    if std::env::var_os("LIGHTFARM_BLESS").is_some() {
        std::fs::write(&path, &generated).expect("write the header");
        eprintln!("rewrote {}", path.display());
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "{} is stale (or missing): the C ABI changed. Refresh it with\n    {REFRESH}\n\
         and commit it. Generated header:\n{generated}",
        path.display()
    );
}

#[test]
fn generated_header_declares_every_entry_point_and_type() {
    let generated = generate(&crate_dir());
    for name in [
        "typedef struct LfRuntime LfRuntime;",
        "LfRuntime *lf_runtime_new(const uint8_t *bytes, size_t len);",
        "void lf_runtime_free(LfRuntime *rt);",
        "size_t lf_last_error(char *buf, size_t cap);",
        "size_t lf_runtime_texel_count(const LfRuntime *rt);",
        "bool lf_runtime_has_drt(const LfRuntime *rt);",
        "bool lf_runtime_has_full(const LfRuntime *rt);",
        "int32_t lf_runtime_apply(LfRuntime *rt,",
        "int32_t lf_runtime_apply_delta(LfRuntime *rt,",
        "int32_t lf_runtime_direct_from_point_lights(const LfRuntime *rt,",
        "int32_t lf_runtime_texel_positions(const LfRuntime *rt, float *out, size_t len);",
        "int32_t lf_runtime_texel_normals(const LfRuntime *rt, float *out, size_t len);",
        "int32_t lf_runtime_texel_albedo(const LfRuntime *rt, float *out, size_t len);",
        "int32_t lf_runtime_texel_sizes(const LfRuntime *rt, float *out, size_t len);",
        "int32_t lf_runtime_atlas_size(const LfRuntime *rt, uint32_t *width, uint32_t *height);",
        "int32_t lf_runtime_atlas_texels(const LfRuntime *rt, uint32_t *xy, size_t len);",
        "size_t lf_runtime_surface_count(const LfRuntime *rt);",
        "int64_t lf_runtime_surface(const LfRuntime *rt,",
        "float position[3];",
        "float intensity[3];",
        "LF_METHOD_MRT = 0,",
        "LF_METHOD_DRT = 1,",
        "LF_METHOD_FULL = 2,",
        "LF_STATUS_OK = 0,",
        "LF_STATUS_NULL_POINTER = -1,",
        "LF_STATUS_PANIC = -7,",
        "LF_STATUS_BAD_INDEX = -10,",
        "#define LF_DIRECT_SAMPLES_PER_EDGE 4",
        "#define LF_PROBE_FLOATS 27",
        "size_t lf_runtime_probe_count(const LfRuntime *rt);",
        "int32_t lf_runtime_apply_probes(LfRuntime *rt, const float *leaving_rgb, size_t leaving_len);",
        "int32_t lf_runtime_apply_probes_delta_in_spans(LfRuntime *rt,",
        "int32_t lf_runtime_probe_field(const LfRuntime *rt, float *out, size_t len);",
        "int32_t lf_runtime_probe_irradiance(const LfRuntime *rt,",
        "#include <stddef.h>",
    ] {
        assert!(
            generated.contains(name),
            "header lacks `{name}`:\n{generated}"
        );
    }
    assert!(
        !generated.contains("set_last_error") && !generated.contains("status_call"),
        "only extern \"C\" items are exported"
    );
}
