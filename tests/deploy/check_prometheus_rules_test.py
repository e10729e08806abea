#!/usr/bin/env python3
"""check_prometheus_rules.py finds each kind of mistake (fixtures/bad-rules*.yml)
and nothing else: the check that guards the Prometheus example can fail.

  check_prometheus_rules_test.py --api-doc docs/api.md
"""
import argparse
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
RULES = os.path.join(HERE, "fixtures", "bad-rules.yml")
TESTS = os.path.join(HERE, "fixtures", "bad-rules.test.yml")

# (file, line, what): the findings expected, each once, in any order.
EXPECTED = [
    (RULES, 11, "metric gyrotherm_lab_outbox_pendng_records is not in docs/api.md's metrics table"),
    (RULES, 18, "gyrotherm_lab_relay_state{state=\"refusd\"}: 'refusd' is not one of the documented values"),
    (RULES, 18, "gyrotherm_state{state=\"crashed\"}: 'crashed' is not one of the documented values"),
    (RULES, 27, "gyrotherm_modbus_connected has no label 'sensor' in docs/api.md"),
    (RULES, 27, "recording rule station:gyrotherm_nothing:ratio is not defined in the rules"),
    (TESTS, 10, "gyrotherm_temperature_celsius{sensor=\"lid\"}: 'lid' is not one of the documented values"),
    (RULES, 26, "alert BadLabel: no severity label"),
    (RULES, 26, "alert BadLabel: its summary does not name the station"),
    (RULES, 31, "alert Untested: no description annotation"),
    (RULES, 31, "alert Untested has no alert_rule_test"),
    (RULES, 8, "recording rule station:gyrotherm_db_commit_seconds:p99 has no promql_expr_test"),
]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--api-doc", required=True)
    args = parser.parse_args()
    checker = os.path.join(HERE, "check_prometheus_rules.py")
    result = subprocess.run(
        [sys.executable, checker, "--api-doc", args.api_doc, "--rules", RULES, "--tests", TESTS],
        capture_output=True,
        text=True,
    )
    lines = [l for l in result.stdout.splitlines() if "remove it from PENDING" not in l]
    failures = []
    if result.returncode != 1:
        failures.append(f"exit status {result.returncode}, expected 1 (stderr: {result.stderr.strip()})")
    unmatched = list(lines)
    for path, line, what in EXPECTED:
        found = [l for l in unmatched if l.startswith(f"{path}:{line}:") and what in l]
        if found:
            unmatched.remove(found[0])
        else:
            failures.append(f"not found: '{path}:{line}: …{what}…'")
    failures += [f"unexpected: '{l}'" for l in unmatched]
    if failures:
        print("check_prometheus_rules.py on the bad fixtures:")
        print("\n".join("  " + f for f in failures))
        print("its output:")
        print(result.stdout + result.stderr)
        return 1
    print(f"ok: the {len(EXPECTED)} mistakes of the fixtures found, nothing else")
    return 0


if __name__ == "__main__":
    sys.exit(main())
