"""The batch spec: a base task plus a sweep, or a list of task files, expanded into plan jobs.

A spec is a YAML mapping::

    base: lbr7_reach.yaml                    # a task file (relative to the spec's directory)
    sweep:                                   # key path -> values; the cartesian product of all axes
      x1.q: {random: {count: 100, within: limits, seed: 7}}
      T: [0.8, 1.0, 1.2]                     # a list of values
      N: {grid: {start: 8, stop: 32, num: 4}}
    outputs: [mcap]                          # per-plan files: none | csv | mcap (or a list)
    starts: 1                                # multi-start per plan (see hoc_cli.multistart)
    seed: 0

or ``tasks: [a.yaml, "more/*.yaml"]`` (files and globs, relative to the spec) instead of
base + sweep, or a bare YAML list of the same. Nothing here solves anything: ``expand`` turns a
spec into ``Job`` s, each the fully resolved task document and its id, a content hash.
"""
from __future__ import annotations

import copy
import glob
import hashlib
import itertools
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hoc_cli.errors import TaskError
from hoc_cli.io.task import load_task, load_yaml
from hoc_cli.report.inputs import MAX_STARTS

SPEC_KEYS = ("base", "sweep", "tasks", "outputs", "starts", "seed")
OUTPUT_KINDS = ("csv", "mcap")
MAX_JOBS = 1_000_000
EXPAND_S = 1e-4  # expanding and checking one swept plan [s] (measured: 0.9 s for 10 000)
EXPAND_WARN_PLANS = 100_000  # warn before expanding a sweep larger than this (over about 10 s)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's emitter when present: 5x faster
_PART = re.compile(r"^([A-Za-z_][\w-]*)((?:\[\d+\])*)$")


@dataclass(frozen=True, eq=False)
class Job:
    """One plan: ``doc`` the resolved task (None when ``source`` is not a YAML mapping: the worker reports why).

    id : content hash of the resolved task (the URDF by its SHA-256), 16 hex digits;
    source : absolute path of the task file the plan comes from (the base of a sweep), against which
    a relative ``robot`` is resolved; text : the task file's text ("" for a swept task: see
    ``yaml_text``); swept : key path -> value.
    """

    id: str
    source: str
    doc: dict | None
    text: str
    swept: dict = field(default_factory=dict)
    starts: int | None = None
    seed: int | None = None

    def yaml_text(self) -> str:
        """The task as YAML text (stored in MCAP outputs): the file's text, or a swept task's document
        written out (on the worker: it is most of the cost of expanding a sweep).
        """
        if self.text or self.doc is None:
            return self.text
        return yaml.dump(self.doc, Dumper=_DUMPER, sort_keys=False, default_flow_style=None)


@dataclass(frozen=True, eq=False)
class Batch:
    """An expanded spec: the unique jobs (first occurrence kept), the sweep keys and the per-plan outputs."""

    jobs: list[Job]
    sweep_keys: list[str]
    outputs: tuple[str, ...]
    duplicates: int = 0

    @property
    def identity(self) -> str:
        """The spec's identity: a hash of what it asks for (its plans' ids and the per-plan outputs).

        Two specs with the same identity solve the same plans into the same files, however they are
        written (key order, comments, file names, a sweep or the same tasks listed); it is stored with
        the results so that ``--resume`` never merges another spec's rows.
        """
        return _digest({"plans": sorted(job.id for job in self.jobs), "outputs": sorted(self.outputs)})


def load_spec(spec: str | Path | dict | list, *, where: Path | None = None) -> Batch:
    """Read a spec (a file, a parsed mapping or list, or a list of task paths/globs) and expand it.

    ``where`` is the directory relative paths in a mapping or list are taken from (default: cwd).
    Raises ``TaskError`` (exit 2) naming the spec file and key for a malformed spec.
    """
    if isinstance(spec, (str, Path)):
        path = Path(spec)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise TaskError(f"cannot be read ({exc.__class__.__name__}; expected a batch spec or task YAML)",
                            file=path) from None
        try:
            doc = load_yaml(text)
        except yaml.YAMLError as exc:
            raise TaskError(f"invalid YAML: {getattr(exc, 'problem', None) or exc}", file=path) from None
        if isinstance(doc, dict) and "robot" in doc:  # a single task file
            return expand({"tasks": [path.name]}, path=path, where=path.parent)
        return expand(doc, path=path, where=path.parent)
    return expand(spec, path=None, where=where or Path("."))


def expand(doc: Any, *, path: Path | None, where: Path) -> Batch:
    """The jobs of a parsed spec; see the module docstring."""
    label = path if path is not None else "<spec>"
    fail = _failer(label)
    if isinstance(doc, list):
        doc = {"tasks": doc}
    if not isinstance(doc, dict):
        raise fail("", "a mapping with base and sweep (or tasks), or a list of task files", doc)
    for k in doc:
        if k not in SPEC_KEYS:
            raise TaskError(f"unknown key {k!r} (expected one of: {', '.join(SPEC_KEYS)})", file=label, key=str(k))
    if ("base" in doc) == ("tasks" in doc):
        raise TaskError("expected exactly one of 'base' (with 'sweep') or 'tasks'", file=label)
    outputs = _outputs(doc.get("outputs"), fail)
    # absent: each task's own solver.starts / solver.seed (default 1 and 0)
    starts = _integer(doc["starts"], "starts", 1, fail, MAX_STARTS) if "starts" in doc else None
    seed = _integer(doc["seed"], "seed", 0, fail) if "seed" in doc else None
    if "tasks" in doc:
        if "sweep" in doc:
            raise TaskError("'sweep' needs 'base' (a sweep varies one base task)", file=label, key="sweep")
        jobs = [_file_job(p, starts, seed) for p in _task_files(doc["tasks"], where, fail)]
        keys: list[str] = []
    else:
        jobs, keys = _sweep_jobs(doc, where, starts, seed, label, fail)
    unique: dict[str, Job] = {}
    for job in jobs:
        unique.setdefault(job.id, job)
    return Batch(jobs=list(unique.values()), sweep_keys=keys, outputs=outputs, duplicates=len(jobs) - len(unique))


def _failer(label):
    def fail(key: str, expected: str, got: Any) -> TaskError:
        text = repr(got)
        return TaskError(f"expected {expected}, got {text if len(text) <= 60 else text[:57] + '...'}",
                         file=label, key=key or None)
    return fail


def _integer(value: Any, key: str, minimum: int, fail, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise fail(key, f"an integer >= {minimum}" + (f" and <= {maximum}" if maximum else ""), value)
    if maximum is not None and value > maximum:
        raise fail(key, f"an integer >= {minimum} and <= {maximum}", value)
    return int(value)


def _outputs(value: Any, fail) -> tuple[str, ...]:
    if value is None or value == "none" or value == []:
        return ()
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) and v in OUTPUT_KINDS for v in items):
        raise fail("outputs", "none, csv, mcap or a list of csv and mcap", value)
    return tuple(dict.fromkeys(items))


def _task_files(entries: Any, where: Path, fail) -> list[Path]:
    if isinstance(entries, str):
        entries = [entries]
    if not isinstance(entries, list) or not entries or not all(isinstance(e, str) for e in entries):
        raise fail("tasks", "a non-empty list of task files or glob patterns", entries)
    files: list[Path] = []
    for i, entry in enumerate(entries):
        pattern = entry if Path(entry).is_absolute() else str(where / entry)
        found = sorted(glob.glob(pattern)) if glob.has_magic(entry) else [pattern]
        if not found or not all(Path(f).is_file() for f in found):
            raise fail(f"tasks[{i}]", "an existing task file or a glob matching task files", entry)
        files.extend(Path(os.path.abspath(f)) for f in found)
    return files


def _file_job(path: Path, starts: int | None, seed: int | None) -> Job:
    text = path.read_text(encoding="utf-8", errors="replace")
    try:
        doc = load_yaml(text)
    except yaml.YAMLError:
        doc = None
    if not isinstance(doc, dict):
        return Job(id=_digest({"text": text}), source=str(path), doc=None, text=text, starts=starts, seed=seed)
    return Job(id=task_id(doc, path, starts, seed), source=str(path), doc=doc, text=text, starts=starts, seed=seed)


def _sweep_jobs(doc: dict, where: Path, starts: int | None, seed: int | None, label, fail) -> tuple[list[Job], list[str]]:
    base = doc["base"]
    if not isinstance(base, str):
        raise fail("base", "a task file path", base)
    base_path = Path(os.path.abspath(Path(base) if Path(base).is_absolute() else where / base))
    task = load_task(base_path, purpose="plan")  # a broken base is an input error, not 1000 error rows
    base_doc = load_yaml(task.text)
    sweep = doc.get("sweep") or {}
    if not isinstance(sweep, dict):
        raise fail("sweep", "a mapping key path -> values", sweep)
    axes: list[list[Any]] = []
    keys: list[str] = []
    model = None
    for key, spec in sweep.items():
        where_key = f"sweep.{key}"
        parts = _key_path(key, where_key, label)
        if isinstance(spec, dict) and "random" in spec:
            if model is None and _wants_limits(spec["random"]):
                from hoc_cli.io.robot import load_model

                model = load_model(task)
            values = _random(spec, parts, base_doc, model, where_key, fail)
        elif isinstance(spec, dict) and "grid" in spec:
            values = _grid(spec, where_key, fail)
        elif isinstance(spec, list) and spec:
            values = list(spec)
        else:
            raise fail(where_key, "a non-empty list of values, {random: {...}} or {grid: {...}}", spec)
        axes.append(values)
        if math.prod(len(a) for a in axes) > MAX_JOBS:  # before the next axis is drawn
            raise TaskError(f"the sweep has more than {MAX_JOBS} plans (expected at most {MAX_JOBS})", file=label,
                            key=where_key)
        keys.append(str(key))
    total = math.prod(len(a) for a in axes)
    if total > MAX_JOBS:
        raise TaskError(f"the sweep has {total} plans (expected at most {MAX_JOBS})", file=label, key="sweep")
    if total > EXPAND_WARN_PLANS:
        from hoc_cli.report.console import warn

        warn(f"the sweep has {total} plans: checking and expanding them takes about {total * EXPAND_S:.0f} s "
             "before the batch starts")
    paths = [_key_path(k, k, label) for k in keys]
    models: dict = {}
    for key, parts, values in zip(keys, paths, axes):  # each value alone on the base: a wrong key names itself
        for value in values:
            alone = copy.deepcopy(base_doc)
            _set(alone, parts, value, f"sweep.{key}", label)
            _refuse_unknown_keys(alone, base_path, [key], label, models)
    jobs = []
    for combo in itertools.product(*axes):
        resolved = copy.deepcopy(base_doc)
        for key, parts, value in zip(keys, paths, combo):
            _set(resolved, parts, value, f"sweep.{key}", label)
        if len(keys) > 1:  # every variant, as its worker will parse it (one axis: each value was checked above)
            _refuse_unknown_keys(resolved, base_path, keys, label, models)
        jobs.append(Job(id=task_id(resolved, base_path, starts, seed), source=str(base_path), doc=resolved,
                        text="", swept=dict(zip(keys, combo)), starts=starts, seed=seed))
    return jobs, keys


#: the messages of ``hoc_cli.io.task`` and ``load_model`` for a key or joint name that does not exist
#: (as opposed to a value that is invalid, which becomes the plan's error row)
_NAME_ERRORS = ("unknown ", "is not a task joint", "not a movable joint", "no such joint")


def _refuse_unknown_keys(doc: dict, base_path: Path, keys: list[str], label, models: dict | None = None) -> None:
    """TaskError (exit 2) when the swept task ``doc`` has a key the task schema does not know.

    The task is parsed as its worker will parse it (``hoc_cli.io.task.parse_task``, about 60 µs)
    and its joint-indexed keys resolved against its robot (loaded once per robot, joints and locked
    joints into ``models``): a key (or a joint name used as a key) that does not exist is refused
    here, naming the sweep key(s) that set it; an invalid value (``T: -1``) is left to become that
    plan's error row.
    """
    from hoc_cli.errors import HocError
    from hoc_cli.io.task import parse_task, resolve

    try:
        task = parse_task(copy.deepcopy(doc), path=base_path, text="", purpose="plan")
        if models is not None:
            spec = (str(task.robot), task.joints, tuple(sorted(task.locked.items())) if task.locked else ())
            if spec not in models:
                from hoc_cli.io.robot import load_model

                try:
                    models[spec] = load_model(task)
                except TaskError:
                    raise
                except HocError:  # a URDF that cannot be used: the plan's error row says why
                    models[spec] = None
            if models[spec] is not None:
                resolve(task, models[spec].joint_names)
    except TaskError as exc:
        if not any(m in exc.detail if m != "unknown " else exc.detail.startswith(m) for m in _NAME_ERRORS):
            return
        where = exc.key or ""
        named = [k for k in keys if where == k or where.startswith((k + ".", k + "[")) or k.startswith(where + ".")]
        swept = ", ".join(f"sweep.{k}" for k in (named or keys))
        raise TaskError(f"in the swept task, {where}: {exc.detail}", file=label, key=swept) from None


def _key_path(key: Any, where_key: str, label) -> list[str | int]:
    if not isinstance(key, str) or not key:
        raise TaskError(f"expected a key path such as x1.q, x1.q[2] or solver.tol, got {key!r}", file=label,
                        key=where_key)
    parts: list[str | int] = []
    for piece in key.split("."):
        m = _PART.match(piece)
        if not m:
            raise TaskError(f"expected a key path such as x1.q, x1.q[2] or solver.tol, got {key!r}", file=label,
                            key=where_key)
        parts.append(m.group(1))
        parts.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return parts


def _set(doc: dict, parts: list[str | int], value: Any, where_key: str, label) -> None:
    node: Any = doc
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                raise TaskError(f"index [{part}] is not in the base task's list", file=label, key=where_key)
            if last:
                node[part] = value
            else:
                node = node[part]
            continue
        if not isinstance(node, dict):
            raise TaskError(f"{part!r} cannot be set: the base task has a list there (use [i])", file=label,
                            key=where_key)
        if last:
            node[part] = value
        else:
            if not isinstance(node.get(part), (dict, list)):
                node[part] = {}
            node = node[part]


def _get(doc: Any, parts: list[str | int]) -> Any:
    for part in parts:
        try:
            doc = doc[part]
        except (KeyError, IndexError, TypeError):
            return None
    return doc


def _wants_limits(spec: Any) -> bool:
    return isinstance(spec, dict) and spec.get("within") == "limits"


def _random(spec: dict, parts: list, base_doc: dict, model, where_key: str, fail) -> list:
    r = spec["random"]
    if len(spec) != 1 or not isinstance(r, dict) or set(r) - {"count", "within", "seed"}:
        raise fail(where_key, "{random: {count: K, within: limits | [low, high] | [[low, high], ...], seed: S}}",
                   spec)
    count = _integer(r.get("count"), f"{where_key}.random.count", 1, fail, MAX_JOBS)
    seed = _integer(r.get("seed", 0), f"{where_key}.random.seed", 0, fail)
    low, high = _bounds(r.get("within"), parts, base_doc, model, f"{where_key}.random.within", fail)
    rng = np.random.default_rng(seed)
    draws = rng.uniform(low, high, size=(count,) + low.shape)
    return [d.tolist() if low.ndim else float(d) for d in draws]


def _bounds(within: Any, parts: list, base_doc: dict, model, key: str, fail) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) arrays, scalar or (n,), for a random axis."""
    if within == "limits":
        if model is None or len(parts) < 2 or parts[0] not in ("x0", "x1") or parts[1] != "q" or len(parts) > 3:
            raise fail(key, "'limits' only for x0.q, x1.q or one joint of them (x1.q[i], x1.q.JOINT)", within)
        names = list(model.joint_names)
        lo, hi = np.asarray(model.lower, float), np.asarray(model.upper, float)
        if len(parts) == 3:
            j = parts[2] if isinstance(parts[2], int) else (names.index(parts[2]) if parts[2] in names else -1)
            if not 0 <= j < len(names):
                raise fail(key, f"a joint of the task ({', '.join(names)})", parts[2])
            names, lo, hi = [names[j]], lo[j], hi[j]
        bad = [n for n, a, b in zip(names, np.atleast_1d(lo), np.atleast_1d(hi))
               if not (np.isfinite(a) and np.isfinite(b) and a < b)]
        if bad:
            raise fail(key, "finite position limits in the URDF, or explicit [low, high]",
                       f"none for {', '.join(bad)}")
        return np.asarray(lo), np.asarray(hi)
    pair = np.asarray(within, dtype=float) if _numeric(within) else None
    if pair is None or pair.ndim not in (1, 2) or pair.shape[-1] != 2 or not np.all(pair[..., 0] <= pair[..., 1]):
        raise fail(key, "limits, [low, high] or a list of [low, high] per component", within)
    low, high = pair[..., 0], pair[..., 1]
    if pair.ndim == 1:
        base = _get(base_doc, parts)
        if isinstance(base, list):  # one range for every component of a vector key
            low, high = np.full(len(base), float(low)), np.full(len(base), float(high))
    return low, high


def _numeric(x: Any) -> bool:
    if isinstance(x, bool):
        return False
    if isinstance(x, (int, float)):
        return math.isfinite(x)
    return isinstance(x, list) and bool(x) and all(_numeric(v) for v in x)


def _grid(spec: dict, where_key: str, fail) -> list:
    g = spec["grid"]
    form = "{grid: {start: a, stop: b, num: K}} or {grid: {start: a, stop: b, step: h}}"
    if len(spec) != 1 or not isinstance(g, dict) or set(g) - {"start", "stop", "num", "step"} \
            or not {"start", "stop"} <= set(g) or ("num" in g) == ("step" in g):
        raise fail(where_key, form, spec)
    a, b = g["start"], g["stop"]
    if not (_numeric(a) and _numeric(b)) or np.shape(a) != np.shape(b):
        raise fail(f"{where_key}.grid", "numbers (or equal-length lists) for start and stop", [a, b])
    integral = all(isinstance(v, int) for v in np.ravel([a, b]).tolist() + ([g.get("step")] if "step" in g else []))
    if "num" in g:
        num = _integer(g["num"], f"{where_key}.grid.num", 1, fail, MAX_JOBS)
        pts = np.linspace(np.asarray(a, float), np.asarray(b, float), num)
    else:
        h = g["step"]
        if not _numeric(h) or isinstance(h, list) or h <= 0 or np.ndim(a):
            raise fail(f"{where_key}.grid.step", "a number > 0 (with scalar start and stop)", h)
        k = math.floor((b - a) / h * (1 + 1e-12)) + 1 if b >= a else 0
        if k < 1 or k > MAX_JOBS:
            raise fail(f"{where_key}.grid", f"start <= stop and at most {MAX_JOBS} points", g)
        pts = a + h * np.arange(k, dtype=float)
    if integral and np.all(pts == np.round(pts)):
        return np.round(pts).astype(int).tolist()
    return pts.tolist()


def task_id(doc: dict, path: Path, starts: int | None = None, seed: int | None = None) -> str:
    """Content hash of a resolved task: its keys and values, with the robot as the SHA-256 of the URDF.

    Two jobs with the same id solve the same problem (the task file's name and comments do not count).
    """
    body = dict(doc)
    robot = body.get("robot")
    if isinstance(robot, str):
        urdf = Path(robot) if Path(robot).is_absolute() else path.parent / robot
        digest = _file_sha256(str(urdf))
        body["robot"] = {"urdf_sha256": digest} if digest else {"missing": str(urdf)}
    solver = body.get("solver") if isinstance(body.get("solver"), dict) else {}
    if starts is not None and (starts > 1 or solver.get("starts", 1) != starts):
        # the spec's starts when they change what is solved (a task's own solver.starts is in its keys)
        body = {"task": body, "starts": starts, "seed": seed or 0}
    return _digest(body)


_URDF_HASHES: dict[str, str] = {}


def _file_sha256(path: str) -> str | None:
    if path not in _URDF_HASHES:
        try:
            _URDF_HASHES[path] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            return None  # missing file: the worker reports it; the id stays a hash of the rest
    return _URDF_HASHES[path]


def _digest(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
