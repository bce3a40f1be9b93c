"""Count the reports of a ./dev sanitize run: the log files AddressSanitizer and
UndefinedBehaviorSanitizer wrote (one per process that had something to say) in REPORTS_DIR.

    python scripts/sanitizer_reports.py REPORTS_DIR SUPPRESSIONS

Every report is printed. A report that a rule of SUPPRESSIONS matches (third-party code, each
rule with its reason there) is printed and counted apart; every other one counts, and so does a
log line that is part of no report (a sanitizer warning). The last line is
"sanitizer reports: N"; the exit status is 1 when N > 0.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

PID = r"^==(?:[^=\s]+==)?\d+=="  # ==1234== or, with log_exe_name, ==python==1234==
ASAN_START = re.compile(PID + r"ERROR: |^AddressSanitizer: CHECK failed|" + PID + r"AddressSanitizer CHECK failed")
ASAN_END = re.compile(PID + r"ABORTING")
UBSAN = re.compile(r"runtime error: ")
FRAME = re.compile(r"^\s+#\d+ ")
QUIET = re.compile(r"^(=+|\s*)$")  # ASan's rule of '=' before a report, blank lines


def reports(text: str) -> tuple[list[str], list[str]]:
    """The reports in one log file, and the lines that belong to none."""
    found, stray, current, asan = [], [], None, False
    for line in text.splitlines():
        if ASAN_START.search(line):
            if current:
                found.append("\n".join(current))
            current, asan = [line], True
        elif UBSAN.search(line) and not asan:
            if current:
                found.append("\n".join(current))
            current = [line]
        elif current is not None and (asan or FRAME.match(line) or line.startswith("SUMMARY: UndefinedBehavior")):
            current.append(line)
            if asan and ASAN_END.match(line):
                found.append("\n".join(current))
                current, asan = None, False
        else:
            if current:
                found.append("\n".join(current))
                current = None
            if not QUIET.match(line):
                stray.append(line)
    if current:
        found.append("\n".join(current))
    return found, stray


def rules(path: Path) -> list[tuple[str, list[re.Pattern]]]:
    """Each line not a comment: a name, then regular expressions joined by '&&' that must all
    occur in a report for the rule to match it."""
    out = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, _, rest = line.partition(" ")
        out.append((name, [re.compile(p.strip(), re.MULTILINE) for p in rest.split("&&")]))
    return out


def main(argv: list[str]) -> int:
    directory, suppressions = Path(argv[1]), rules(Path(argv[2]))
    counted, suppressed = 0, {}
    for log in sorted(p for p in directory.iterdir() if p.is_file()):
        found, stray = reports(log.read_text(errors="replace"))
        for report in found:
            rule = next((name for name, patterns in suppressions if all(p.search(report) for p in patterns)), None)
            if rule is None:
                counted += 1
                print(f"--- {log.name}: a report\n{report}\n")
            else:
                suppressed[rule] = suppressed.get(rule, 0) + 1
                print(f"--- {log.name}: suppressed by {rule} (scripts/sanitizer-suppressions.txt)\n{report}\n")
        if stray:
            counted += 1
            print(f"--- {log.name}: sanitizer output outside a report\n" + "\n".join(stray) + "\n")
    for rule, n in sorted(suppressed.items()):
        print(f"suppressed ({rule}): {n}")
    print(f"sanitizer reports: {counted}")
    return 1 if counted else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
