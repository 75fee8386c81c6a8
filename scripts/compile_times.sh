#!/usr/bin/env bash
# Measures how long rustc takes to compile each checked-in generated module in release
# (all six kernels instantiated for f64), one robot at a time, in a scratch crate under
# target/compile-times/. Prints a markdown table; reproduces the book's compile times.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
printf '| robot | lines | release compile (s) |\n|---|---|---|\n'
for dir in generated/*/; do
    robot=$(basename "$dir")
    file=$(ls "$dir"*.rs)
    crate="target/compile-times/$robot"
    mkdir -p "$crate/src"
    cat > "$crate/Cargo.toml" <<TOML
[package]
name = "compile-time-$(echo "$robot" | tr '_' '-')"
version = "0.0.0"
edition = "2021"
[workspace]
TOML
    cat > "$crate/src/main.rs" <<RS
mod robot { include!("$root/$file"); }
fn main() {
    let q = [0.1f64; robot::NV];
    let (a, b, c) = robot::fd_grad(&q, &q, &q);
    let (d, e) = robot::rnea_grad(&q, &q, &q);
    println!("{} {} {} {} {} {} {} {} {}", a[0], b[0][0], c[0][0], d[0][0], e[0][0], robot::rnea(&q, &q, &q)[0], robot::mass_matrix(&q)[0][0], robot::minv(&q)[0][0], robot::fd(&q, &q, &q)[0]);
}
RS
    rm -rf "$crate/target"
    start=$(date +%s.%N)
    (cd "$crate" && cargo build --release --quiet)
    end=$(date +%s.%N)
    printf '| %s | %s | %.1f |\n' "$robot" "$(wc -l < "$file")" "$(python3 -c "print($end - $start)")"
done
