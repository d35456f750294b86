"""Measurements behind ``hoc verify``: the paper's numerical claims, recomputed.

Each check returns ``Measurement`` records (pure maths, no I/O). The CLI prints them
beside the expected values and exits 1 when one misses.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from hoc_cli.elements import ORDERS, HermiteMesh, error_norm


@dataclass(frozen=True)
class Measurement:
    """One checked claim: ``measured`` must lie within ``tolerance`` of ``expected`` (absolute)."""

    claim: str
    measured: float
    expected: float
    tolerance: float
    paper: str = ""
    note: str = ""

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.measured) and abs(self.measured - self.expected) <= self.tolerance)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["passed"] = self.passed
        return d


def convergence_order(h: np.ndarray, err: np.ndarray) -> float:
    """Least-squares slope of log(err) against log(h): the measured order of convergence."""
    h, err = np.asarray(h, float), np.asarray(err, float)
    slope, _ = np.polyfit(np.log(h), np.log(err), 1)
    return float(slope)


def interpolation_errors(order: str, Ns: tuple[int, ...] = (4, 8, 16, 32, 64)) -> tuple[np.ndarray, np.ndarray]:
    """h (len(Ns),) and the error norm ‖sin − Π_h sin‖ on [0, π]: ‖·‖₃ (cubic) or ‖·‖₅ (quintic)."""
    exact = (np.sin, np.cos, lambda t: -np.sin(t))
    hs, errs = [], []
    for N in Ns:
        mesh = HermiteMesh(order, np.pi, N)  # type: ignore[arg-type]
        C = mesh.interpolate(*exact)
        hs.append(mesh.h)
        errs.append(error_norm(mesh, C, exact))
    return np.array(hs), np.array(errs)


def check_interpolation() -> list[Measurement]:
    """Paper §"Accuracy of the interpolations": ‖e‖₃ in h⁴ (cubic), ‖e‖₅ in h⁶ (quintic)."""
    out = []
    for order, expected, norm in (("cubic", 4.0, "‖e‖₃"), ("quintic", 6.0, "‖e‖₅")):
        h, e = interpolation_errors(order)
        out.append(
            Measurement(
                claim=f"interpolation of sin t on [0, π], {order}: order of {norm}, N = 4…64",
                measured=convergence_order(h, e),
                expected=expected,
                tolerance=0.2,
                paper=f"h^{expected:g}",
            )
        )
    return out


CHECKS: dict[str, Callable[[], list[Measurement]]] = {
    "interpolation": check_interpolation,
}


def run_checks(names: list[str] | None = None) -> list[Measurement]:
    """Run the named checks (all by default) in registration order."""
    results: list[Measurement] = []
    for name, fn in CHECKS.items():
        if names is None or name in names:
            results.extend(fn())
    return results
