//! Writes the GGX albedo table that the crate embeds (`src/ggx_albedo.bin`, see the `albedo`
//! module): `cargo run --release -p oxray-render --example ggx_albedo_table`. The file is
//! written to a temporary name and renamed into place.

use oxray_render::albedo::GgxAlbedo;
use std::path::Path;

fn main() -> std::io::Result<()> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/ggx_albedo.bin");
    let tmp = path.with_extension("bin.tmp");
    std::fs::write(&tmp, GgxAlbedo::compute(64).to_bytes())?;
    std::fs::rename(&tmp, &path)?;
    println!("wrote {}", path.display());
    Ok(())
}
