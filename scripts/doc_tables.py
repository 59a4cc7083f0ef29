"""Checks (or rewrites) the tables of docs/EXPERIMENTS.md that are generated from the archive.

usage: python3 scripts/doc_tables.py [--write] [DOC, default docs/EXPERIMENTS.md (a path from the root or absolute)]

A generated table sits between two HTML comments that Markdown does not show:

    <!-- generated: campaign_report.py docs/campaign/results --methods fear-long,random-long --tables per-run -->
    | method | seed | ... |
    <!-- end generated -->

The first names a script of scripts/ and its arguments (run from the repository's root); the
text between the comments must be exactly what that command prints. Without --write, prints a
diff for each block that differs from what the archive gives now and exits 1 (the suite runs
this: `tests/tests/doc_tables.rs` in the coadapt-tests crate); with --write, replaces each block
with the command's output. Only scripts listed in SCRIPTS may be named, so a document cannot
make this run anything else.

Pure Python, no packages: it runs with the system python3.
"""
import difflib
import os
import re
import shlex
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPTS = {"campaign_report.py", "calibration_report.py", "design_bench_report.py", "reference_report.py", "transfer_report.py", "latent_exploration_report.py"}
BLOCK = re.compile(r"^<!-- generated: (.+?) -->\n(.*?)^<!-- end generated -->$", re.M | re.S)


def render(command, where):
    words = shlex.split(command)
    if not words or words[0] not in SCRIPTS:
        sys.exit(f"doc_tables: {where}: `{command}` does not name one of {', '.join(sorted(SCRIPTS))}")
    out = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", words[0]), *words[1:]],
                         cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"doc_tables: {where}: `{command}` failed (exit {out.returncode}):\n{out.stderr}")
    return out.stdout.strip("\n") + "\n"


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    write = "--write" in sys.argv
    path = os.path.join(ROOT, args[0] if args else "docs/EXPERIMENTS.md")
    text = open(path, encoding="utf-8").read()
    blocks = list(BLOCK.finditer(text))
    if not blocks:
        sys.exit(f"doc_tables: {path} has no generated block")
    stale = []
    new_text, last = [], 0
    for m in blocks:
        line = text.count("\n", 0, m.start()) + 1
        want = render(m.group(1), f"{os.path.relpath(path, ROOT)} line {line}")
        have = m.group(2)
        if have != want:
            stale.append((line, m.group(1), have, want))
        new_text.append(text[last:m.start(2)])
        new_text.append(want)
        last = m.end(2)
    new_text.append(text[last:])
    if write:
        if stale:
            with open(path + ".tmp", "w", encoding="utf-8") as f:
                f.write("".join(new_text))
            os.replace(path + ".tmp", path)
        print(f"doc_tables: {len(blocks)} generated blocks, {len(stale)} rewritten")
        return
    for line, command, have, want in stale:
        print(f"doc_tables: line {line}: the table differs from `{command}`:")
        sys.stdout.writelines(difflib.unified_diff(have.splitlines(True), want.splitlines(True), "document", "archive"))
    if stale:
        print(f"doc_tables: {len(stale)} of {len(blocks)} generated blocks disagree with the archive; "
              "rerun with --write after checking that the archive is right")
        sys.exit(1)
    print(f"doc_tables: {len(blocks)} generated blocks agree with the archive")


if __name__ == "__main__":
    main()
