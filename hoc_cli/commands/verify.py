"""``hoc verify``: print every measured claim beside its expectation; exit 1 on a miss."""
from __future__ import annotations

from rich.table import Table

from hoc_cli.commands.common import EXIT_OK, EXIT_UNMET
from hoc_cli.errors import TaskError
from hoc_cli.report.console import stderr_console
from hoc_cli.report.jsonio import print_json
from hoc_cli.verification import CHECKS, run_checks


def run(as_json: bool = False, quiet: bool = False, only: list[str] | None = None) -> int:
    if only:
        unknown = [c for c in only if c not in CHECKS]
        if unknown:
            raise TaskError(f"unknown check {unknown[0]!r} (expected one of: {', '.join(CHECKS)})", key="--only")
    results = run_checks(only)
    ok = all(r.passed for r in results)
    if as_json:
        print_json({"passed": ok, "measurements": [r.to_dict() for r in results]})
    console = stderr_console(quiet=quiet or as_json)
    table = Table(title="hoc verify: the paper's claims, measured")
    for col in ("claim", "paper", "expected", "measured", "ok"):
        table.add_column(col)
    for r in results:
        table.add_row(r.claim, r.paper, r.expectation, f"{r.measured:.6g}",
                      "yes" if r.passed else "NO")
    console.print(table)
    return EXIT_OK if ok else EXIT_UNMET
