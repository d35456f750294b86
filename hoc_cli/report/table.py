"""``hoc plan``'s summary table on standard error: the JSON summary's main keys as text lines.

User text (joint names, paths) is shown literally: ``Text`` is never parsed as rich markup. ``rich``
is imported only when a table is made.
"""
from __future__ import annotations


def summary_table(summary: dict):
    """The summary as a rich ``Table`` (standard error, on a terminal or with --progress)."""
    from rich.table import Table
    from rich.text import Text

    table = Table(title="hoc plan", show_header=False)
    table.add_column("key")
    table.add_column("value")
    for key in ("cost", "cost_type", "converged", "iterations", "evaluations", "grad_norm", "wall_time_s",
                "N", "mesh", "order", "T", "dJ_dT", "T_bound", "boundary_error", "J_error_estimate"):
        if key not in summary or (key == "mesh" and summary[key] == "uniform"):
            continue  # goals have no error estimate, joint goals no dJ_dT; the mesh shown when non-uniform only
        v = summary[key]
        table.add_row(key, f"{v:.12g}" if isinstance(v, float) else str(v))
    # user text (joint names, paths) is shown literally: Text is never parsed as rich markup
    table.add_row("max |u|", Text(", ".join(f"{j} {v:.4g}" for j, v in zip(summary["joints"], summary["max_abs_u"]))))
    table.add_row("status", Text(str(summary["status"])))
    reached = summary.get("reached")
    if reached:
        errors = ", ".join(f"{k.removesuffix('_error')} to {reached[k]:.2g}" for k in
                           ("position_error", "orientation_error", "velocity_error") if reached.get(k) is not None)
        table.add_row("reached", Text(f"{reached['link']}: {errors}"))
    table.add_row("limits", Text(str(summary.get("limits_mode", "report"))))
    active = summary.get("active_limits") or []
    table.add_row("active limits", Text("none" if not active else "; ".join(
        f"{a['joint']} {a['kind']} " + ", ".join(f"[{t0:.3g}, {t1:.3g}] s" for t0, t1 in a["intervals"]) for a in active)))
    viol = summary["limit_violations"]
    table.add_row("limit violations", Text("none" if not viol else "; ".join(
        f"{v['joint']} {v['kind']} {v['worst']:.4g}" for v in viol)))
    clearance = summary.get("min_clearance")
    if clearance:
        table.add_row("min clearance", Text(f"{clearance['distance']:.4g} m ({' – '.join(clearance['pair'])} at t = "
                                            f"{clearance['t']:.4g} s; proven >= {clearance['lower_bound']:.4g} m)"))
        table.add_row("collisions", Text("none" if not summary["collisions"] else "; ".join(
            f"{' – '.join(c['pair'])} [{c['interval'][0]:.3g}, {c['interval'][1]:.3g}] s" for c in summary["collisions"])))
    if "starts" in summary:
        table.add_row("starts", "; ".join(
            f"{o['start']}{'*' if o['start'] == summary['best_start'] else ''} "
            f"{'-' if o['cost'] is None else format(o['cost'], '.6g')} {o['status']}" for o in summary["starts"]))
    table.add_row("outputs", Text(", ".join(summary["outputs"])))
    return table
