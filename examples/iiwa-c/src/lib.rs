//! iiwa's checked-in kernels behind their C ABI: `cargo build --release -p iiwa-c` makes
//! `target/release/libgrid_iiwa.a` and `libgrid_iiwa.so`, which `generated/grid_iiwa/iiwa14.h`
//! declares. Any robot works the same way: `grid-gen ROBOT.urdf --backend rust,c -o DIR`, then
//! these two `include!`s with its file names.

pub mod iiwa14 {
    include!("../../../generated/grid_iiwa/iiwa14.rs");
}
include!("../../../generated/grid_iiwa/iiwa14_c.rs");
