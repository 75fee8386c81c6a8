#!/usr/bin/env python3
"""One kernel's two `--solve` routes side by side: for each robot, the CLI generates the
kernel alone under `--solve A` and `--solve B` (B by a second CLI with `--cli-b`, to
compare two commits), one program includes both modules
(`rustc -C opt-level=3 -C target-cpu=native`, so the dispatcher runs the fma copy), checks
that they agree, and times them interleaved (30 rounds of 200 calls each, the first two
dropped; medians). Prints one line per robot: both times, their ratio, the largest
difference and the largest entry.

Usage: python3 scripts/solve_ab.py [--kernel minv|fd_grad|contact_fd|contact_fd_grad]
[--routes minv,auto] [--cli-b PATH] [CASE ...], a CASE being `URDF`, `URDF:floating` or
`URDF:SCENE.toml` (the scene's own `outputs` dropped; every candidate contact active where
it has `contact_mask`; default: the cases of the book's table, Operations, "M⁻¹ from M's
factorisation"). Needs the CLI (`cargo build --release -p grid-gen-cli
--no-default-features`; `$GRID_GEN` overrides its path) and rustc. A benchmark, not a
test: run it on an idle machine.
"""

import argparse
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.environ.get("GRID_GEN", os.path.join(ROOT, "target", "release", "grid-gen"))
CASES = [
    "robots/grid_iiwa.urdf",
    "robots/panda.urdf",
    "robots/grid_hyq.urdf",
    "robots/grid_atlas.urdf",
    "robots/grid_iiwa.urdf:floating",
    "robots/ur5.urdf:floating",
    "robots/grid_hyq.urdf:floating",
    "tests/fixtures/go2.urdf:floating",
    "robots/grid_atlas.urdf:floating",
]

TIMING = """{{
    let mut s = 7u64;
    let mut q = [0.0f64; {a}::NQ];
    for x in q.iter_mut() {{ *x = lcg(&mut s); }}
    if {a}::NQ != {a}::NV {{
        let n = (q[3] * q[3] + q[4] * q[4] + q[5] * q[5] + q[6] * q[6]).sqrt();
        for k in 3..7 {{ q[k] /= n; }}
    }}
    let mut qd = [0.0f64; {a}::NV];
    let mut tau = [0.0f64; {a}::NV];
    for x in qd.iter_mut().chain(tau.iter_mut()) {{ *x = lcg(&mut s); }}
    let active = [1.0f64; {ncontacts}];
    let (x, y) = ({a}::{kernel}({args}), {b}::{kernel}({args}));
    let (mut diff, mut big) = (0.0f64, 0.0f64);
    for (r, t) in {flat_x}.zip({flat_y}) {{
        diff = diff.max((r - t).abs());
        big = big.max(r.abs());
    }}
    let (mut ta, mut tb, mut acc) = (Vec::new(), Vec::new(), 0.0);
    let last = q.len() - 1;
    for round in 0..30 {{
        for which in 0..2 {{
            let t0 = Instant::now();
            for _ in 0..200 {{
                q[last] += 1e-9;
                let m = if which == 0 {{ {a}::{kernel}({bargs}) }} else {{ {b}::{kernel}({bargs}) }};
                acc += {first};
            }}
            let ns = t0.elapsed().as_nanos() as f64 / 200.0;
            if round >= 2 {{ if which == 0 {{ ta.push(ns) }} else {{ tb.push(ns) }} }}
        }}
    }}
    ta.sort_by(|a, b| a.total_cmp(b));
    tb.sort_by(|a, b| a.total_cmp(b));
    let (ma, mb) = (ta[ta.len() / 2], tb[tb.len() / 2]);
    black_box(acc);
    println!("| {case} | {{:.0}} | {{:.0}} | {{:.2}}x | {{:.1e}} of {{:.1e}} |", ma, mb, mb / ma, diff, big);
}}"""


# How each kernel is called, and the entries compared between the routes.
STATE = ("&q, &qd, &tau", "black_box(&q), black_box(&qd), black_box(&tau)")
KERNELS = {
    "minv": ("&q", "black_box(&q)", "m[0][0]", "{v}.iter().flatten()"),
    "fd_grad": (
        *STATE,
        "m.1[0][0]",
        "{v}.0.iter().chain({v}.1.iter().flatten()).chain({v}.2.iter().flatten())",
    ),
    "contact_fd": (*STATE, "m.0[0]", "{v}.0.iter().chain({v}.1.iter())"),
    "contact_fd_grad": (
        *STATE,
        "m.2[0][0]",
        "{v}.0.iter().chain({v}.1.iter())"
        + "".join(f".chain({{v}}.{k}.iter().flatten())" for k in range(2, 8)),
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kernel", default="minv", choices=sorted(KERNELS))
    ap.add_argument("--routes", default="minv,auto")
    ap.add_argument("--cli-b", default=CLI, help="the CLI that generates B (default: the one of A)")
    ap.add_argument("cases", nargs="*", default=CASES)
    args = ap.parse_args()
    routes = args.routes.split(",")
    if len(routes) != 2:
        sys.exit("error: --routes takes two solves, A,B")
    if not os.access(CLI, os.X_OK):
        sys.exit(f"error: {CLI} is missing: cargo build --release -p grid-gen-cli --no-default-features")
    with tempfile.TemporaryDirectory() as tmp:
        lines = ["#![allow(warnings)]", "use std::hint::black_box;", "use std::time::Instant;"]
        lines.append(
            "fn lcg(s: &mut u64) -> f64 { *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); ((*s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0 }"
        )
        timings = []
        for i, case in enumerate(args.cases):
            urdf, _, extra = case.partition(":")
            text = ""
            if extra.endswith(".toml"):
                with open(os.path.join(ROOT, extra)) as f:
                    text = "".join(l for l in f if not l.startswith("outputs"))
            scene = os.path.join(tmp, f"kernel{i}.toml")
            with open(scene, "w") as f:
                f.write(f'outputs = ["{args.kernel}"]\n' + text)
            masked = "contact_mask = true" in text
            mods = []
            for cli, route in zip([CLI, args.cli_b], routes):
                out = os.path.join(tmp, f"m{i}_{len(mods)}_{route}")
                cmd = [cli, os.path.join(ROOT, urdf), "--scene", scene, "--solve", route, "-o", out]
                if extra == "floating":
                    cmd.append("--floating-base")
                subprocess.run(cmd, check=True, capture_output=True)
                rs = next(f for f in os.listdir(out) if f.endswith(".rs"))
                name = os.path.basename(out)
                lines.append(f'mod {name} {{ include!("{os.path.join(out, rs)}"); }}')
                mods.append(name)
            call, bcall, first, flat = KERNELS[args.kernel]
            if masked:
                call, bcall = call + ", &active", bcall + ", black_box(&active)"
            timings.append(
                TIMING.format(
                    a=mods[0],
                    b=mods[1],
                    kernel=args.kernel,
                    case=case,
                    args=call,
                    bargs=bcall,
                    first=first,
                    flat_x=flat.format(v="x"),
                    flat_y=flat.format(v="y"),
                    ncontacts=f"{mods[0]}::NCONTACTS" if masked else "0",
                )
            )
        lines.append("fn main() {")
        lines.extend(timings)
        lines.append("}")
        main_rs = os.path.join(tmp, "main.rs")
        with open(main_rs, "w") as f:
            f.write("\n".join(lines))
        exe = os.path.join(tmp, "ab")
        subprocess.run(["rustc", "--edition", "2021", "-C", "opt-level=3", "-C", "target-cpu=native", "-o", exe, main_rs], check=True)
        print(f"| case | `{args.kernel}`, solve {routes[0]} (ns) | solve {routes[1]} (ns) | ratio | largest difference |")
        print("|---|---:|---:|---:|---:|")
        sys.stdout.flush()
        subprocess.run([exe], check=True)


if __name__ == "__main__":
    main()
