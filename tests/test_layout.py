"""The package's stages form a one-way chain: render <- model <- scene <- {fit, eval} <- edit <-
{cli, viewer} <- entry points, with util and loop below everything. Read from the source with `ast`: a cycle or
an upward import fails here."""

import ast
import os

import gae_jax

PACKAGE = os.path.dirname(gae_jax.__file__)
# A module may import from its own stage and from stages of a lower rank only.
RANK = {"util": 0, "colours": 0, "render": 1, "loop": 1, "model": 2, "scene": 3, "instructions": 4,
        "evaluation": 5, "fit": 5, "edit": 6, "cli": 7, "viewer": 7, "reconstruct": 8,
        "train": 8, "evaluate": 8, "demo": 8, "view": 8, "__init__": 9}


def stage_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports():
    """(module, imported gae_jax module) pairs of every .py file of the package."""
    for root, _, files in os.walk(PACKAGE):
        for name in files:
            if not name.endswith(".py"):
                continue
            path = os.path.join(root, name)
            rel = os.path.relpath(path, os.path.dirname(PACKAGE))[:-3].replace(os.sep, ".")
            module = rel[:-len(".__init__")] if rel.endswith(".__init__") else rel
            with open(path, encoding="utf-8") as f:
                tree = ast.parse(f.read(), path)
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    targets = [node.module] if node.module != "gae_jax" else [
                        f"gae_jax.{a.name}" for a in node.names]
                elif isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                else:
                    continue
                for target in targets:
                    if target.startswith("gae_jax."):
                        yield module, target


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
    graph = {}
    for module, target in imports():
        graph.setdefault(module, set()).add(target)
    state = {}

    def visit(node, path):
        state[node] = "open"
        for nxt in graph.get(node, ()):
            if state.get(nxt) == "open":
                raise AssertionError("cycle: " + " -> ".join(path + [nxt]))
            if nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for node in list(graph):
        if node not in state:
            visit(node, [node])


def test_modules_stay_small():
    long = []
    for root, _, files in os.walk(PACKAGE):
        for name in files:
            if name.endswith(".py"):
                with open(os.path.join(root, name), encoding="utf-8") as f:
                    n = sum(1 for _ in f)
                if n > 450 or (name == "train.py" and root == PACKAGE and n > 200):
                    long.append(f"{name}: {n} lines")
    assert not long, long
