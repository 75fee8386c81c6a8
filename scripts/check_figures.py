#!/usr/bin/env python3
"""Checks the README's headline speed table against the dated run it names: each row's
times and ratios must be the ones in that run's report (the table `scripts/bench.sh`
prints), so the README cannot drift from its source. Exits 1 naming every mismatch."""

import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# README row label -> the report's robot column.
ROBOTS = {
    "iiwa (7 joints)": "grid_iiwa",
    "HyQ (12 joints)": "grid_hyq",
    "Atlas (30 joints)": "grid_atlas",
    "HyQ, floating base": "grid_hyq.hyq_floating (floating base)",
    "Atlas, floating base": "grid_atlas, floating base (`grid-gen bench`)",
    "HyQ, `round_angles = 1e-11`": "grid_hyq.hyq_round_angles (round_angles 1e-11)",
    "HyQ, floating, `round_angles = 1e-11`": "grid_hyq.hyq_floating_round_angles (floating base, round_angles 1e-11)",
}


def main() -> int:
    readme = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    section = readme.split("\n## Speed\n", 1)[1].split("\n## ", 1)[0]
    run = re.search(r"\]\((docs/bench/[^)]+\.md)\)", section)
    if not run:
        print("README.md, Speed: no link to the dated run its table comes from")
        return 1
    # Report rows: robot, kernel, generated, reference, Pinocchio, [CppADCodeGen,] vs reference,
    # vs Pinocchio[, vs CppADCodeGen] (runs before 2026-11-25 have no CppADCodeGen columns).
    report = {}
    for line in open(os.path.join(ROOT, run.group(1)), encoding="utf-8"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 7:
            report[(cells[0], cells[1])] = (cells[2], cells[6])
        elif len(cells) == 9:
            report[(cells[0], cells[1])] = (cells[2], cells[7], cells[8])
    wrong, rows = [], 0
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) not in (5, 7) or cells[0] not in ROBOTS:
            continue
        rows += 1
        robot = ROBOTS[cells[0]]
        # README rows: robot, then per kernel its time and ratios (vs Pinocchio[, vs CppADCodeGen]).
        per = (len(cells) - 1) // 2
        for n, kernel in enumerate(("fd_grad", "rnea_grad")):
            got = tuple(cells[1 + n * per : 1 + (n + 1) * per])
            want = report.get((robot, kernel))
            if want != got:
                wrong.append(f"README.md Speed, {cells[0]} {kernel}: {' '.join(got)}; {run.group(1)} says {want}")
    if rows != len(ROBOTS):
        wrong.append(f"README.md Speed: {rows} rows found, expected {len(ROBOTS)}")
    for w in wrong:
        print(w)
    print(f"README speed table: {len(wrong)} mismatches" if wrong else f"README speed table: {rows} rows match {run.group(1)}")
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
