//! Generates the iiwa's dynamics into OUT_DIR at build time.

fn main() -> Result<(), grid_gen::BuildError> {
    grid_gen::Builder::new().urdf("../../robots/grid_iiwa.urdf").file_name("iiwa.rs").compile()?;
    Ok(())
}
