"""Where the suite's wall time went: per group of tests (tests/conftest.py), when it started and ended relative to
the first test, how long its tests ran and how long they waited for the host (tests/host_share.py).

    ZENTRACK_TEST_TIMELINE=out/timeline.jsonl bash .ci/run
    python tests/timeline.py out/timeline.jsonl
"""
from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("timeline", type=Path, help="the JSON lines a run wrote (ZENTRACK_TEST_TIMELINE)")
    parser.add_argument("--top", type=int, default=20, help="how many groups to list, longest span first")
    args = parser.parse_args(argv)
    try:
        rows = [json.loads(line) for line in args.timeline.read_text().splitlines() if line.strip()]
    except (OSError, ValueError) as e:
        print(f"timeline: cannot read {args.timeline}: {e}", file=sys.stderr)
        return 2
    if not rows:
        print(f"timeline: {args.timeline} holds no test", file=sys.stderr)
        return 2
    t0 = min(r["asked"] for r in rows)
    groups: dict[str, list[dict]] = collections.defaultdict(list)
    for r in rows:
        groups[r["group"]].append(r)
    print(f"{len(rows)} tests, {max(r['ended'] for r in rows) - t0:.0f} s from the first to the last")
    print(f"{'group':32} {'tests':>5} {'start':>7} {'end':>7} {'ran':>7} {'waited':>7}  worker")
    spans = sorted(groups.items(), key=lambda kv: -(max(r["ended"] for r in kv[1]) - min(r["asked"] for r in kv[1])))
    for name, tests in spans[:args.top]:
        ran = sum(r["ended"] - r["started"] for r in tests)
        waited = sum(r["started"] - r["asked"] for r in tests)
        workers = ",".join(sorted({r["worker"] for r in tests}))
        print(f"{name[:32]:32} {len(tests):5d} {min(r['asked'] for r in tests) - t0:7.0f} "
              f"{max(r['ended'] for r in tests) - t0:7.0f} {ran:7.0f} {waited:7.0f}  {workers}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
