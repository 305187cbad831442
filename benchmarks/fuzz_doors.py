"""The fuzz suite of the input doors (tests/test_fuzz_doors.py, issue 42) in its long profile: at least
20,000 examples over all doors, random (not derandomized), each door's examples and findings counted.

    python benchmarks/fuzz_doors.py [--profile long] [-k EXPR] [--seed N] [--log /tmp/fuzz_doors.log]

Runs ``pytest tests/test_fuzz_doors.py --hypothesis-profile=long --hypothesis-show-statistics -p
no:cacheprovider`` (with ``-p fuzz_strategies``, which registers the profiles before pytest
configures Hypothesis) and prints one row per door: examples tried (the generate phase's passing and
failing ones, and the shrink phase's), the share the door refused, the phase's time, and what it
found (nothing, or the property that failed with its minimal example); then the total wall and CPU
time. Exits non-zero when a property fails (a hole: a traceback, an overrun, a write outside). The
whole pytest output is kept in ``--log``.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TESTS = "tests/test_fuzz_doors.py"


def pytest_command(profile: str, expr: str | None, seed: int | None) -> list[str]:
    """The pytest run of the suite in ``profile`` (``expr``: pytest's -k; ``seed``: Hypothesis' seed)."""
    cmd = [sys.executable, "-m", "pytest", TESTS, "-p", "fuzz_strategies", f"--hypothesis-profile={profile}"]
    cmd += ["--hypothesis-show-statistics", "-p", "no:cacheprovider", "-q", "-rf"]
    if expr:
        cmd += ["-k", expr]
    if seed is not None:
        cmd += [f"--hypothesis-seed={seed}"]
    return cmd


def statistics(text: str) -> dict[str, dict]:
    """Per test of Hypothesis' statistics: examples (passing + failing) per phase, the phase's seconds,
    the share of each event (accepted, refused) in the generate phase, why it stopped."""
    out: dict[str, dict] = {}
    test, phase = None, None
    for line in text.splitlines():
        head = re.match(r"^(\S+::(test_\w+)):$", line.strip())
        if head:
            test, phase = head.group(2), None
            out[test] = {"examples": {}, "seconds": {}, "events": {}, "stopped": ""}
            continue
        if test is None:
            continue
        s = out[test]
        m = re.match(r"\s*- during (\w+) phase \(([0-9.]+) seconds\):", line)
        if m:
            phase = m.group(1)
            s["seconds"][phase] = float(m.group(2))
            continue
        m = re.match(r"\s*- (\d+) passing(?: examples?)?, (\d+) failing", line)
        if m and phase:
            s["examples"][phase] = int(m.group(1)) + int(m.group(2))
            continue
        m = re.match(r"\s*\* ([0-9.]+)%, (.+)$", line)
        if m and phase == "generate":
            s["events"][m.group(2).strip()] = float(m.group(1))
            continue
        m = re.match(r"\s*- Stopped because (.+)$", line)
        if m:
            s["stopped"] = m.group(1).strip()
    return out


def _section_finding(body: str) -> str:
    """What one failed test's section of pytest's report says: each distinct error (its first line)
    and the minimal example's draws, shortened."""
    errors = re.findall(r"^(?:E\s+|\s+\| )([\w.]*(?:Error|Exception|Exceeded|Flaky\w*|Interrupt)\b:?.*)$", body, re.M)
    errors = list(dict.fromkeys(e.strip()[:200] for e in errors if not e.startswith("ExceptionGroup")))
    draws = re.findall(r"Draw \d+ \(([^)]*)\): (.*)$", body, re.M)
    shown = "; ".join(f"{k}={v.strip()[:60]}" for k, v in draws[:6])
    return " / ".join(errors[:3]) + (f"; minimal example: {shown}" if shown else "")


def findings(text: str) -> dict[str, str]:
    """Per failed test, what failed (:func:`_section_finding`); a test during which the process died
    (a C library's abort, a segfault: faulthandler's "Fatal Python error") is named with it."""
    found = {}
    fatal = re.search(r"Fatal Python error: (\w+)(.{0,20000}?)(?:Extension modules|\Z)", text, re.S)
    if fatal:
        tests = re.findall(r"test_fuzz_doors\.py\", line \d+ in (test_\w+)", fatal.group(2))
        where = re.findall(r'File "([^"]+)", line (\d+) in (\w+)', fatal.group(2))
        at = f" in {where[0][2]} ({Path(where[0][0]).name}:{where[0][1]})" if where else ""
        found[tests[-1] if tests else "the suite"] = f"the process died: Fatal Python error: {fatal.group(1)}{at}"
    parts = re.split(r"^_{3,} (test_\w+) _{3,}$", text, flags=re.M)
    for name, body in zip(parts[1::2], parts[2::2]):
        found[name] = _section_finding(body.split("short test summary info")[0]) or "failed"
    for m in re.finditer(r"^FAILED \S+::(test_\w+)(?: - (.*))?$", text, re.M):
        found.setdefault(m.group(1), (m.group(2) or "failed").strip()[:300])
    return found


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="long", help="Hypothesis profile of tests/fuzz_strategies.py (long, fast)")
    ap.add_argument("-k", dest="expr", help="only the doors pytest's -k expression selects")
    ap.add_argument("--seed", type=int, help="Hypothesis' seed (default: random; the long profile is not derandomized)")
    ap.add_argument("--log", default="/tmp/fuzz_doors.log", help="where the whole pytest output is kept")
    args = ap.parse_args()
    # COLUMNS: pytest cuts its one-line reasons to the terminal's width
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "tests"), str(REPO / "workflow")]), "COLUMNS": "400"}
    cmd = pytest_command(args.profile, args.expr, args.seed)
    print("$", " ".join(cmd[1:]), flush=True)
    t0 = time.monotonic()
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    wall = time.monotonic() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    text = res.stdout + "\n" + res.stderr
    Path(args.log).write_text(text)
    stats, found = statistics(text), findings(text)
    rows = ["| door | examples | shrink | refused % | seconds | found |", "|---|---|---|---|---|---|"]
    total = 0
    for test in sorted(set(stats) | set(found)):
        s = stats.get(test, {"examples": {}, "seconds": {}, "events": {}})
        n = s["examples"].get("generate", 0) + s["examples"].get("explicit", 0)
        total += n
        seconds = sum(s["seconds"].values())
        what = found.get(test, "nothing")
        rows.append(
            f"| {test.removeprefix('test_')} | {n} | {s['examples'].get('shrink', 0)} | "
            f"{s['events'].get('refused', 0):.0f} | {seconds:.1f} | {what.replace('|', '/')} |"
        )
    print("\n".join(rows))
    summary = re.findall(r"^=*\s*(\d+ (?:passed|failed|error).*?)\s*=*$", text, re.M)
    print(
        f"\n{total:,} examples over {len(stats)} doors ({args.profile} profile); "
        f"wall {wall:.0f} s, CPU {usage.ru_utime + usage.ru_stime:.0f} s; "
        f"pytest: {summary[-1] if summary else 'no summary'} (rc {res.returncode}); log: {args.log}"
    )
    if res.returncode and not stats:
        print("\n".join(ln for ln in text.splitlines()[-40:] if not ln.startswith("Extension modules"))[-3000:])
    return 1 if res.returncode else 0


if __name__ == "__main__":
    sys.exit(main())
