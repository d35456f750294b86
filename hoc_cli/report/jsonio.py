"""The JSON summary as text: non-finite floats as null, numpy values as numbers, strict JSON on standard output."""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float (an absent limit is ±inf) as None, ready for strict JSON."""
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    try:
        import numpy as np
    except ImportError:  # pragma: no cover
        return obj
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.floating) and not np.isfinite(obj):
        return None
    return obj


def validate_json(obj: Any) -> str:
    """Strict JSON text of ``obj`` (raises before any output is written if it cannot be serialised)."""
    return json.dumps(obj, indent=2, allow_nan=False, default=jsonable)


def print_json(obj: Any) -> None:
    """One JSON object on standard output."""
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=jsonable) + "\n")
    sys.stdout.flush()


def jsonable(x: Any) -> Any:
    """``json.dumps``'s ``default``: numpy arrays and scalars as lists and numbers, paths as text."""
    import numpy as np

    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
