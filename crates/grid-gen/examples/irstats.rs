fn main() {
    for r in std::env::args().skip(1) {
        let text = std::fs::read_to_string(&r).unwrap();
        let (m, _) = grid_gen::Model::from_urdf_str(&r, &text, false).unwrap();
        let t = std::time::Instant::now();
        for s in grid_gen::ir::stats(&m, [0.0, 0.0, -9.81]) {
            println!("{r} {} before {} after {} depth {} {:?}", s.kernel, s.before.total(), s.after.total(), s.after.depth, s.after);
        }
        println!("{:?}", t.elapsed());
    }
}
