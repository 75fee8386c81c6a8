# Sourced by scripts/bench.sh and scripts/bench_layouts.sh: bench_exe SEED builds the criterion
# benchmarks (crates/grid-gen-kernels/benches/kernels.rs) of the checkout in the current
# directory, into CARGO_TARGET_DIR if set, linked with their code sections shuffled by SEED
# (rust-lld's --shuffle-sections; 0: cargo's own layout), and prints the executable's path.
# Rebuilding the benchmark crate takes about two minutes per layout.
bench_exe() {
    local args=()
    [ "$1" -gt 0 ] && args=(-C "link-arg=-Wl,--shuffle-sections=.text*=$1")
    cargo rustc --profile bench -p grid-gen-kernels --bench kernels --message-format=json -- "${args[@]}" \
        | grep -o '"executable":"[^"]*"' | tail -1 | cut -d'"' -f4
}
