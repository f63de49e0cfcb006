"""The repository's two trees and the library's floors, stated once and held.

Two trees: ``slipsense/`` is the installable library (what ``pip install slipsense`` gives a robot
builder); ``studies/`` beside it holds the papers' experiments and the grasp analyses that earn the
project's figures (run as ``python -m studies``). The studies import the library; no module of the
library imports the studies.

Inside the library each floor imports only from its own floor and the floors below, and no module
reaches itself through its imports (function-local imports count too).

    base         errors, atomic, cache, paths, config_tree, plots, resources, parallel, progress, alarm,
                 provenance
    sensors      what a sensor is (specs) and the marker maths on one image
    measures     how well a detector did, from replayed traces alone: no I/O, models or training
    recordings   a set of recordings read once (the folder listed once, its sensor, rates, probes), frames
                 and their caches, labels (the hand labels applied), clips, markers tracked in videos
    data in      data, datasets, readers, marker_sequences: what training and evaluation read, built
                 on the recordings
    models       models (the contract, one file per network, streams, runners, ONNX parts), checkpoint
    streaming    the live detector, sources, capture, export: what runs on the robot
    evaluation   the judge: a detector opened once, recordings read once, every run replayed once
    training     the one training loop and its tasks; the operating point and cross-validation judge
    top          api, watch (a source watched through a detector: what ``slipsense watch`` runs),
                 ros_node (the same detector as a ROS 2 node), adapt
    cli          the ``slipsense`` command

The live detector sits below evaluation on purpose: a detector is judged by replaying recordings
through the very object that runs live, so the numbers are the same. Within a floor, no two packages
or modules of ``slipsense/`` import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "slipsense"
STUDIES = ROOT / "studies"
FLOORS = [
    [
        "errors",
        "atomic",
        "cache",
        "paths",
        "config_tree",
        "plots",
        "resources",
        "parallel",
        "progress",
        "alarm",
        "provenance",
        "",
    ],
    ["sensors"],
    ["measures"],
    ["recordings"],
    ["data", "datasets", "readers", "marker_sequences"],
    ["models", "checkpoint"],
    ["streaming"],
    ["evaluation"],
    ["training"],
    ["api", "watch", "ros_node", "adapt"],
    ["cli"],
]
MAX_LINES = 600


def _modules() -> dict[str, Path]:
    mods = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


def _imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the slipsense modules it imports anywhere in its source (resolved to a module)."""
    edges: dict[str, set[str]] = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                wanted = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                wanted = [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for w in wanted:
                while w and w not in mods:
                    w = w.rpartition(".")[0]
                if w and w != name:
                    targets.add(w)
        edges[name] = targets
    return edges


def floor_of(module: str) -> int:
    """The floor of ``slipsense.<module>``: its first name after ``slipsense``."""
    top = module.split(".")[1] if "." in module else ""
    for k, names in enumerate(FLOORS):
        if top in names:
            return k
    raise AssertionError(f"{module} is on no floor: add its package to FLOORS (and the README's layout)")


def test_every_import_goes_to_the_same_floor_or_below():
    edges = _imports(_modules())
    upward = [
        f"{m} (floor {floor_of(m)}) imports {t} (floor {floor_of(t)})"
        for m, ts in sorted(edges.items())
        for t in sorted(ts)
        if floor_of(t) > floor_of(m)
    ]
    assert not upward, "\n".join(upward)


def find_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return groups


def _top(module: str) -> str:
    return module.split(".")[1] if "." in module else ""


def test_the_measures_import_neither_training_models_recordings_nor_streaming():
    edges = _imports(_modules())
    banned = {"training", "models", "recordings", "streaming", "evaluation", "checkpoint", "data", "readers"}
    bad = [f"{m} imports {t}" for m, ts in edges.items() if _top(m) == "measures" for t in ts if _top(t) in banned]
    assert not bad, "\n".join(bad)


def test_no_two_packages_import_each_other():
    """Packages and modules of ``slipsense/`` taken whole: the arrows between them run one way only."""
    edges = _imports(_modules())
    tops: dict[str, set[str]] = {}
    for m, ts in edges.items():
        tops.setdefault(_top(m), set()).update(_top(t) for t in ts if _top(t) != _top(m))
    assert find_cycles(tops) == []


def test_no_import_cycles():
    assert find_cycles(_imports(_modules())) == []


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_no_module_over_600_lines():
    long = {
        name: n for name, p in _modules().items() if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, long


def _imported_names(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    return names


def test_the_library_never_imports_the_studies():
    leaks = [
        f"{p.relative_to(ROOT)} imports {name}"
        for p in sorted(PACKAGE.rglob("*.py"))
        for name in sorted(_imported_names(p))
        if name == "studies" or name.startswith("studies.")
    ]
    assert not leaks, "\n".join(leaks)


def test_the_studies_are_a_tree_of_their_own_with_an_entry_point():
    assert (STUDIES / "__main__.py").is_file() and (STUDIES / "README.md").is_file()
    assert not (PACKAGE / "experiments").exists()
