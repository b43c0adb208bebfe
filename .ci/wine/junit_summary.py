"""Counts, failures and skip reasons from a pytest junit XML file.

    python3 junit_summary.py junit.xml [more.xml ...]

Prints ``N passed, N failed, N error, N skipped``, then the failures and errors grouped by
the first line of their message, then every skip reason with its count (each skip on the
Windows job must say why).
"""

from __future__ import annotations

import collections
import re
import sys
import xml.etree.ElementTree as ET

counts: collections.Counter[str] = collections.Counter()
problems: dict[str, list[str]] = collections.defaultdict(list)
skips: collections.Counter[str] = collections.Counter()
roots = [ET.parse(path).getroot() for path in sys.argv[1:]]
cases = [case for root in roots for case in root.iter("testcase")]
seconds = sum(float(suite.get("time") or 0) for root in roots for suite in root.iter("testsuite"))
for case in cases:
    name = f"{case.get('classname')}::{case.get('name')}"
    outcome = next((k for k in case if k.tag in ("failure", "error", "skipped")), None)
    if outcome is None:
        counts["passed"] += 1
        continue
    counts[outcome.tag] += 1
    message = (outcome.get("message") or "").strip()
    if outcome.tag == "skipped":
        if message == "collection skipped":  # a whole module: the reason is in the text
            message = (outcome.text or "").rsplit("Skipped: ", 1)[-1].removesuffix("')")
        skips[message[:160] or "(no reason)"] += 1
        continue
    first = message.splitlines()[0][:160] if message else outcome.tag
    problems[re.sub(r"0x[0-9a-fA-F]+|\d+(\.\d+)?", "N", first)].append(name)
print(", ".join(f"{counts[k]} {k}" for k in ("passed", "failure", "error", "skipped"))
      + f" in {seconds / 60:.1f} min")
wine = sum(n for reason, n in skips.items() if reason.startswith("Wine "))
print(f"of the skips, {wine} for a gap of Wine's (wine_gap), "
      f"{counts['skipped'] - wine} for another reason")
for key, names in sorted(problems.items(), key=lambda kv: -len(kv[1])):
    print(f"\n[{len(names)}] {key}")
    for name in names[:5]:
        print(f"    {name}")
if skips:
    print("\nskip reasons:")
    for reason, n in skips.most_common():
        print(f"  {n:4d}  {reason}")
