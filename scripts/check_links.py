#!/usr/bin/env python3
"""Checks every relative link and image in README.md and the book (docs/): the file
exists, and an anchor (#...) names a heading of that file, computed as mdBook computes
ids (GitHub's are the same for our headings). Also checks that every page under docs/
is in docs/SUMMARY.md, so that no chapter is left out of the book. Exits 1 with a list of
what is broken."""

import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LINK = re.compile(r"!?\[([^\]]*)\]\(([^)\s]+)\)")


def slug(text: str) -> str:
    """mdBook's `normalize_id` of a heading's text (inline code and links reduced to text)."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"<[^>]*>", "", text)
    out = []
    for ch in text.strip():
        if ch.isalnum() or ch in "_-":
            out.append(ch.lower())
        elif ch.isspace():
            out.append("-")
    return "".join(out)


def prose_lines(path, keep_code=False):
    """The lines outside fenced code blocks, with inline code removed (or, with
    keep_code, only its backticks)."""
    fenced = False
    for number, line in enumerate(open(path, encoding="utf-8"), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            yield number, line.replace("`", "") if keep_code else re.sub(r"`[^`]*`", "", line)


def anchors(path, cache={}):
    if path not in cache:
        seen = {}
        ids = set()
        for _, line in prose_lines(path, keep_code=True):
            m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
            if m:
                base = slug(m.group(2))
                n = seen.get(base, 0)
                ids.add(base if n == 0 else f"{base}-{n}")
                seen[base] = n + 1
        cache[path] = ids
    return cache[path]


def main() -> int:
    pages = [os.path.join(ROOT, "README.md")]
    for folder, _, files in os.walk(os.path.join(ROOT, "docs")):
        pages += [os.path.join(folder, f) for f in files if f.endswith(".md")]
    broken = []
    for page in sorted(pages):
        for number, line in prose_lines(page):
            for m in LINK.finditer(line):
                target = m.group(2)
                if re.match(r"^[a-z]+:", target):
                    continue
                path, _, anchor = target.partition("#")
                dest = os.path.normpath(os.path.join(os.path.dirname(page), path)) if path else page
                where = f"{os.path.relpath(page, ROOT)}:{number}: {target}"
                if not os.path.exists(dest):
                    broken.append(f"{where}: no such file")
                elif anchor and dest.endswith(".md") and anchor not in anchors(dest):
                    broken.append(f"{where}: no heading with id #{anchor} in {os.path.relpath(dest, ROOT)}")
    summary = os.path.join(ROOT, "docs", "SUMMARY.md")
    listed = {os.path.normpath(os.path.join(ROOT, "docs", t.partition("#")[0])) for _, l in prose_lines(summary) for _, t in LINK.findall(l)}
    for page in pages:
        if page.startswith(os.path.join(ROOT, "docs") + os.sep) and page != summary and page not in listed:
            broken.append(f"{os.path.relpath(page, ROOT)}: not in docs/SUMMARY.md")
    for b in broken:
        print(b)
    print(f"{len(pages)} pages checked, {len(broken)} broken links" if broken else f"{len(pages)} pages checked, every link resolves")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
