#!/usr/bin/env python3
"""Regenerates the `socdiff --help` section of README.md from the built binary.
Usage: python3 scripts/readme_help.py [path/to/socdiff]   (default target/release/socdiff)"""
import re, subprocess, sys

binary = sys.argv[1] if len(sys.argv) > 1 else "target/release/socdiff"
readme = open("README.md").read()
start = readme.index("## `socdiff --help`")
end = readme.index("## Layout")
block = readme[start:end]
commands = [""] + re.findall(r"^\$ socdiff (.*) --help$", block, re.M)
parts = []
for cmd in commands:
    out = subprocess.run([binary] + cmd.split() + ["--help"], capture_output=True, text=True, check=True).stdout.rstrip()
    parts.append(out if not cmd else f"$ socdiff {cmd} --help\n{out}")
new = "## `socdiff --help`\n\n```\n" + "\n\n".join(parts) + "\n```\n\n"
open("README.md", "w").write(readme[:start] + new + readme[end:])
print(f"{len(commands)} help texts written")
