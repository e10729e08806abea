#!/usr/bin/env python3
"""Checks the Prometheus example against what the daemon documents.

  check_prometheus_rules.py --api-doc docs/api.md --rules RULES.yml --tests TESTS.yml

- every gyrotherm_* metric named in the rules and their unit tests (input
  series included) is a row of docs/api.md's metrics table (or of PENDING,
  below), and every label matcher on it names a documented label and, for
  `=` and plain `=~` alternatives, a documented value;
- every recording rule used (level:metric:operations) is defined in the rules;
- every alert has a severity label and summary and description annotations
  that name the station ({{ $labels.station }});
- every alert and every recording rule is exercised by the unit tests.

No YAML library (not a dependency of the project): the files are read as
text, which is enough for names, matchers and rule blocks. Exit 0 when all
holds, 1 with one line per finding, 2 on a usage error.
"""
import argparse
import re
import sys

# Metrics the rules may use before docs/api.md documents them (name ->
# {label: values}); empty now. The check fails while a name is in both
# here and docs/api.md, so an entry cannot outlive its reason.
PENDING = {}

# Labels Prometheus attaches to every scraped series (prometheus.yml's
# static_configs give each station target a `station` label).
TARGET_LABELS = {"job", "instance", "station"}

HISTOGRAM_SUFFIXES = ("_bucket", "_sum", "_count")

TOKEN = re.compile(r"(?<![A-Za-z0-9_:.])([A-Za-z_:][A-Za-z0-9_:]*)")
MATCHER = re.compile(r'\s*([A-Za-z_][A-Za-z0-9_]*)\s*(=~|!~|!=|=)\s*"((?:[^"\\]|\\.)*)"\s*,?')
RECORDING_NAME = re.compile(r"^[a-z_]+:[A-Za-z0-9_]+:[A-Za-z0-9_]+$")


def documented_metrics(api_doc):
    """name -> {"type": str, "labels": {label: set of values or None (any)}}
    from the table under '## Metrics'."""
    with open(api_doc, encoding="utf-8") as f:
        text = f.read()
    section = re.search(r"^## Metrics\n(.*?)(?=^## )", text, re.S | re.M)
    if not section:
        raise SystemExit(f"{api_doc}: no '## Metrics' section")
    metrics = {}
    for line in section.group(1).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or not cells[0].startswith("`gyrotherm_"):
            continue
        name = cells[0].strip("`")
        labels = {}
        # "`state` = `idle`, `queued`, …" or "`device`" (values elsewhere)
        for part in re.split(r";", cells[2]):
            m = re.match(r"\s*`([A-Za-z_][A-Za-z0-9_]*)`\s*(=\s*(.*))?$", part)
            if not m:
                continue
            values = re.findall(r"`([^`]*)`", m.group(3) or "")
            labels[m.group(1)] = set(values) if values else None
        metrics[name] = {"type": cells[1], "labels": labels}
    if not metrics:
        raise SystemExit(f"{api_doc}: no metric rows in '## Metrics'")
    return metrics


def strip_comments(text):
    """Whole-line YAML comments only (the files have no trailing ones)."""
    return "\n".join("" if l.lstrip().startswith("#") else l for l in text.splitlines())


def matchers_after(text, pos):
    """The label matchers of a selector starting at text[pos] == '{'."""
    end = text.find("}", pos)
    if end < 0:
        return []
    body = text[pos + 1 : end]
    return [(m.group(1), m.group(2), m.group(3)) for m in MATCHER.finditer(body)]


def check_names(path, text, metrics, recorded, findings):
    for m in TOKEN.finditer(text):
        token = m.group(1)
        line = text.count("\n", 0, m.start()) + 1
        where = f"{path}:{line}"
        if ":" in token:
            if RECORDING_NAME.match(token) and token not in recorded:
                findings.append(f"{where}: recording rule {token} is not defined in the rules")
            continue
        if not token.startswith("gyrotherm_"):
            continue
        name = token
        if name not in metrics:
            base = next((name[: -len(s)] for s in HISTOGRAM_SUFFIXES if name.endswith(s)), None)
            if base in metrics and metrics[base]["type"] == "histogram":
                name = base
            else:
                findings.append(f"{where}: metric {token} is not in docs/api.md's metrics table")
                continue
        if m.end() < len(text) and text[m.end()] == "{":
            allowed = metrics[name]["labels"]
            for label, op, value in matchers_after(text, m.end()):
                if label in TARGET_LABELS or label == "__name__":
                    continue
                if label not in allowed:
                    findings.append(f"{where}: {token} has no label '{label}' in docs/api.md")
                    continue
                values = allowed[label]
                if values is None or op in ("!=", "!~"):
                    continue
                wanted = value.split("|") if op == "=~" else [value]
                for v in wanted:
                    if re.fullmatch(r"[A-Za-z0-9_]+", v) and v not in values:
                        findings.append(
                            f"{where}: {token}{{{label}=\"{v}\"}}: '{v}' is not one of the documented values ({', '.join(sorted(values))})"
                        )


def rule_blocks(text):
    """[(kind 'alert'|'record', name, block text, line)] of a rules file."""
    starts = [m for m in re.finditer(r"^\s*- (alert|record):\s*(\S+)\s*$", text, re.M)]
    blocks = []
    for i, m in enumerate(starts):
        end = starts[i + 1].start() if i + 1 < len(starts) else len(text)
        blocks.append((m.group(1), m.group(2), text[m.start() : end], text.count("\n", 0, m.start()) + 1))
    return blocks


def check_alert_block(path, name, block, line, findings):
    where = f"{path}:{line}: alert {name}"
    if not re.search(r"^\s*severity:\s*(critical|warning|info)\s*$", block, re.M):
        findings.append(f"{where}: no severity label (critical, warning or info)")
    for key in ("summary", "description"):
        m = re.search(rf"^(\s*){key}:(.*(?:\n\1\s+.*)*)", block, re.M)
        if not m:
            findings.append(f"{where}: no {key} annotation")
        elif "$labels.station" not in m.group(2):
            findings.append(f"{where}: its {key} does not name the station ({{{{ $labels.station }}}})")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--api-doc", required=True)
    parser.add_argument("--rules", required=True)
    parser.add_argument("--tests", required=True)
    args = parser.parse_args()

    metrics = documented_metrics(args.api_doc)
    findings = []
    for name in sorted(PENDING):
        if name in metrics:
            findings.append(
                f"{args.api_doc}: {name} is documented now: remove it from PENDING in {sys.argv[0]}"
            )
    for name, labels in PENDING.items():
        metrics.setdefault(name, {"type": "", "labels": labels})

    with open(args.rules, encoding="utf-8") as f:
        rules = strip_comments(f.read())
    with open(args.tests, encoding="utf-8") as f:
        tests = strip_comments(f.read())

    blocks = rule_blocks(rules)
    if not blocks:
        findings.append(f"{args.rules}: no rules")
    recorded = {name for kind, name, _, _ in blocks if kind == "record"}
    check_names(args.rules, rules, metrics, recorded, findings)
    check_names(args.tests, tests, metrics, recorded, findings)

    tested_alerts = set(re.findall(r"^\s*(?:- )?alertname:\s*(\S+)\s*$", tests, re.M))
    test_exprs = "\n".join(re.findall(r"^\s*- expr:\s*(.*)$", tests, re.M))
    for kind, name, block, line in blocks:
        if kind == "alert":
            check_alert_block(args.rules, name, block, line, findings)
            if name not in tested_alerts:
                findings.append(f"{args.rules}:{line}: alert {name} has no alert_rule_test in {args.tests}")
        elif not re.search(rf"(?<![A-Za-z0-9_:]){re.escape(name)}(?![A-Za-z0-9_:])", test_exprs):
            findings.append(f"{args.rules}:{line}: recording rule {name} has no promql_expr_test in {args.tests}")

    for finding in findings:
        print(finding)
    if findings:
        return 1
    print(f"ok: {len(blocks)} rules; their metrics are documented, alerts named and tested")
    return 0


if __name__ == "__main__":
    sys.exit(main())
