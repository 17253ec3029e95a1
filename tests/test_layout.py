"""The package's stages form a one-way chain: render <- model <- scene <- {fit, eval} <- edit <-
run <- viewer <- entry points, with util and loop below everything. Read from the source with
`ast`: a cycle or an upward import fails here, and so does an entry point that grows past its
flags."""

import ast
import os
import textwrap

import gae_jax

PACKAGE = os.path.dirname(gae_jax.__file__)
# A module may import from its own stage and from stages of a lower rank only.
RANK = {"util": 0, "colours": 0, "render": 1, "loop": 1, "model": 2, "scene": 3, "instructions": 4,
        "evaluation": 5, "fit": 5, "edit": 6, "run": 7, "cli": 7, "viewer": 8, "reconstruct": 9,
        "train": 9, "evaluate": 9, "demo": 9, "view": 9, "batch": 9, "__init__": 10}
ENTRY_POINTS = ("reconstruct", "train", "evaluate", "demo", "view")
ENTRY_POINT_LINES = 200


def stage_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def module_names(root: str) -> dict:
    """{dotted module name: file path} of every .py file of the package at `root`."""
    top = os.path.basename(root)
    out = {}
    for folder, _, files in os.walk(root):
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                rel = os.path.relpath(path, os.path.dirname(root))[:-3].replace(os.sep, ".")
                out[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = path
    assert all(m.split(".")[0] == top for m in out)
    return out


def imports(root: str = PACKAGE):
    """(module, imported module) pairs of the package at `root`, wherever the import statement
    sits (a function's lazy import counts). `from a.b import c` names the module `a.b.c` when
    that is a module of the package, else `a.b`."""
    modules = module_names(root)
    top = os.path.basename(root)
    for module, path in modules.items():
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), path)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules
                           else node.module for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for target in dict.fromkeys(targets):
                if target.startswith(top + "."):
                    yield module, target


def find_cycle(pairs) -> list:
    """One import cycle among (module, imported module) pairs as a path [a, b, ..., a], or []."""
    graph = {}
    for module, target in pairs:
        graph.setdefault(module, set()).add(target)
    state = {}

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt, path + [nxt])
                if found:
                    return found
        state[node] = "done"
        return []

    for node in sorted(graph):
        if node not in state:
            found = visit(node, [node])
            if found:
                return found
    return []


def test_every_module_belongs_to_a_stage():
    stages = {stage_of(m) for m, _ in imports()} | {stage_of(t) for _, t in imports()}
    assert stages <= set(RANK), stages - set(RANK)


def test_no_upward_or_sideways_import():
    bad = []
    for module, target in imports():
        a, b = stage_of(module), stage_of(target)
        if a != b and RANK[b] >= RANK[a]:
            bad.append(f"{module} imports {target}")
    assert not bad, "\n".join(bad)


def test_no_import_cycle_between_modules():
    cycle = find_cycle(imports())
    assert not cycle, "cycle: " + " -> ".join(cycle)


def test_the_cycle_check_sees_lazy_imports_of_sibling_modules(tmp_path):
    """A circle of the kind `from pkg.model import makehuman` inside a function of head.py and
    `from pkg.model import head` at the top of makehuman.py: both name the package `pkg.model`
    in the statement, the modules only in the imported names."""
    model = tmp_path / "pkg" / "model"
    model.mkdir(parents=True)
    for folder in (tmp_path / "pkg", model):
        (folder / "__init__.py").write_text("")
    (model / "head.py").write_text(textwrap.dedent("""
        def make_head(kind):
            if kind == "makehuman":
                from pkg.model import makehuman
                return makehuman.load()
    """))
    (model / "makehuman.py").write_text("from pkg.model import head\n\ndef load():\n"
                                        "    return head\n")
    pairs = set(imports(str(tmp_path / "pkg")))
    assert ("pkg.model.head", "pkg.model.makehuman") in pairs
    assert find_cycle(pairs) in (["pkg.model.head", "pkg.model.makehuman", "pkg.model.head"],
                                 ["pkg.model.makehuman", "pkg.model.head",
                                  "pkg.model.makehuman"])
    (model / "makehuman.py").write_text("def load():\n    return 1\n")
    assert find_cycle(imports(str(tmp_path / "pkg"))) == []


def test_oracles_are_imported_by_studies_only():
    """The oracle editors read the ideal edit: nothing in the package may use them."""
    users = sorted({m for m, t in imports() if t == "gae_jax.run.oracle"})
    assert users == [], users


def test_modules_stay_small_and_entry_points_keep_flags_only():
    long = []
    for module, path in module_names(PACKAGE).items():
        with open(path, encoding="utf-8") as f:
            n = sum(1 for _ in f)
        entry = (module.count(".") == 1 and module.split(".")[1] in ENTRY_POINTS
                 or module.endswith(".__main__"))
        if n > 450 or (entry and n > ENTRY_POINT_LINES):
            long.append(f"{module}: {n} lines")
    assert not long, long
