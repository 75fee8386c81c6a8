#!/usr/bin/env python3
"""What the compiled kernels spend their instructions on, read from the assembly that rustc
emits for a generated module's `fma` copy in f64: per kernel, the instructions of its part
functions, the floating-point arithmetic among them, the stack traffic (spills and reloads:
memory operands on %rsp or %rbp), the other memory traffic (the module's scratch array,
inputs and outputs) and the register moves. This machine's VM exposes no hardware counters
(`perf stat` reports instructions and cycles as <not supported>), so this static count is
the measurement the speed chapter uses for register pressure.

Usage: scripts/asm_stats.py [--avx512] MODULE.rs [KERNEL ...]   (default: rnea_grad fd_grad)
Prints a Markdown table. Needs rustc; compiles with -C opt-level=3 -C target-cpu=x86-64-v3
(AVX2 and FMA, what the `fma` copy is built for), or x86-64-v4 for the `avx512` copy of a
module generated with `--avx512`.

       scripts/asm_stats.py --object LIBRARY.so FUNCTION [FUNCTION ...]
counts the same classes in functions of a compiled library (objdump -d), such as the C that
CppADCodeGen prints for Pinocchio in scripts/bench.sh (target/bench/cg/*.so), which is
straight-line too.
"""
import collections
import pathlib
import re
import subprocess
import sys
import tempfile

args = sys.argv[1:]
OBJECT = args[:1] == ["--object"]
COPY = "fma"
if args[:1] == ["--avx512"]:
    # The module's AVX-512 copy (`--avx512`), which has 32 vector registers to the fma copy's 16.
    COPY, args = "avx512", args[1:]
if OBJECT:
    # objdump's AT&T lines, `  addr:\top args` under `<function>:` headers, as rustc's
    # `\top args` under `label:`; only the named functions' lines are kept.
    module, kernels = pathlib.Path(args[1]).resolve(), args[2:]
    if not kernels:
        sys.exit("usage: scripts/asm_stats.py --object LIBRARY.so FUNCTION [FUNCTION ...]")
    dump = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "-M", "att", str(module)],
                          check=True, capture_output=True, text=True).stdout
    lines, COPY = [], "object"
    for line in dump.splitlines():
        header = re.match(r"^[0-9a-f]+ <(.+)>:$", line)
        if header:
            lines.append(f"{header.group(1)}:")
            continue
        insn = re.match(r"^\s+[0-9a-f]+:\t(.*)$", line)
        if insn and lines:
            lines.append("\t" + insn.group(1))
    lines.append("\t.cfi_endproc")
else:
    module = pathlib.Path(args[0]).resolve()
    kernels = args[1:] or ["rnea_grad", "fd_grad"]

    with tempfile.TemporaryDirectory() as tmp:
        wrapper = pathlib.Path(tmp) / "wrapper.rs"
        # Taking each kernel's address instantiates it in f64 and keeps it in the object.
        uses = "\n".join(f"    m::{COPY}::{k}::<f64> as *const () as usize," for k in kernels)
        wrapper.write_text(
            "#![allow(dead_code, clippy::all)]\n"
            f'mod m {{ include!("{module}"); }}\n'
            f"#[inline(never)]\npub fn keep() -> usize {{\n    [\n{uses}\n    ].iter().sum()\n}}\n"
        )
        asm = pathlib.Path(tmp) / "out.s"
        subprocess.run(
            ["rustc", "--edition", "2021", "--crate-type", "lib", "--emit", "asm", "-C", "opt-level=3",
             "-C", "target-cpu=" + ("x86-64-v4" if COPY == "avx512" else "x86-64-v3"), "-C", "symbol-mangling-version=v0", str(wrapper), "-o", str(asm)],
            check=True,
        )
        lines = asm.read_text().splitlines()

ARITH = re.compile(r"^v(fn?m(add|sub)\d+[sp][sd]|(mul|add|sub|div|sqrt|xor|and|max|min)[sp][sd])$")
counts = collections.defaultdict(collections.Counter)
current = None
for line in lines:
    if re.match(r"^\S+:$", line) and not line.startswith("."):
        label = line[:-1]
        current = None
        for k in kernels:
            # v0 mangling: `...3fma15rnea_grad_part0dEB6_` (a part), `...3fma9rnea_graddEB6_`.
            if (label == k) if OBJECT else re.search(rf"{len(COPY)}{COPY}\d+{k}(_part\d+)?dE", label):
                current = k
        if OBJECT and current is None:
            continue
        continue
    if current is None:
        continue
    if line.startswith("\t.cfi_endproc"):
        current = None
        continue
    if not line.startswith("\t") or line.startswith("\t."):
        continue
    parts = line.split(None, 1)
    op, args = parts[0], (parts[1] if len(parts) > 1 else "")
    c = counts[current]
    c["instructions"] += 1
    stack = "(%rsp" in args or "(%rbp" in args
    memory = "(" in args
    if ARITH.match(op):
        c["arithmetic"] += 1
        if stack:
            c["arithmetic on a stack operand"] += 1
    elif op.startswith("vmov") or op.startswith("mov"):
        if stack:
            # AT&T: the destination is last.
            c["stack stores" if args.rstrip().endswith(")") else "stack loads"] += 1
        elif memory:
            c["other loads and stores"] += 1
        else:
            c["register moves"] += 1
    elif op == "call" or op.startswith("call"):
        c["calls"] += 1
    else:
        c["other"] += 1

cols = ["instructions", "arithmetic", "stack loads", "stack stores", "arithmetic on a stack operand",
        "other loads and stores", "register moves", "calls", "other"]
print(f"{module.name}:\n" if OBJECT else f"{module.name}, `{COPY}` copy, f64:\n")
print("| kernel | " + " | ".join(cols) + " | stack share |")
print("|---|" + "---:|" * (len(cols) + 1))
for k in kernels:
    c = counts[k]
    if not c["instructions"]:
        sys.exit(f"error: no instructions found for {k} in the assembly")
    stack = c["stack loads"] + c["stack stores"] + c["arithmetic on a stack operand"]
    print(f"| {k} | " + " | ".join(str(c[x]) for x in cols) + f" | {stack / c['instructions']:.0%} |")
