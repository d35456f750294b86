"""`hoc verify` through the CLI: JSON on stdout, exit 0 when every claim is met."""
import json

from typer.testing import CliRunner

from hoc_cli.cli import app


def test_verify_json_reports_interpolation_orders_and_passes():
    r = CliRunner().invoke(app, ["verify", "--json", "--only", "interpolation"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["passed"] is True
    orders = {o: m["measured"] for m in doc["measurements"] for o in ("cubic", "quintic") if f"], {o}:" in m["claim"]}
    assert abs(orders["cubic"] - 4) < 0.2 and abs(orders["quintic"] - 6) < 0.2


def test_verify_rejects_an_unknown_check_with_exit_2():
    r = CliRunner().invoke(app, ["verify", "--only", "nonsense"])
    assert r.exit_code == 2 and "--only" in r.stderr


def test_full_verify_json_passes_and_covers_every_claim_of_the_paper():
    r = CliRunner().invoke(app, ["verify", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    claims = " ".join(m["claim"] for m in doc["measurements"])
    for topic in ("interpolation", "validation", "pendulum period", "2-link arm"):
        assert topic in claims
    assert doc["passed"] and all(m["passed"] for m in doc["measurements"])
