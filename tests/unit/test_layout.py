"""The layout rules of the code base, checked on the source tree:

* no import cycle between modules, and none between stages once the command-line glue
  (``*.cli`` modules, which compose stages by design) is left out;
* no hand-written module over the size limit;
* every rule id a typed error is raised with is registered in ``fbaconf/rules.py``;
* no document or module names a repository file that does not exist.
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path

import pytest

from fbaconf.rules import CODES, RULES

ROOT = Path(__file__).resolve().parents[2]
MAX_LINES = 700


NOT_INSTALLED = {"tests", "benchmarks", "examples", "docs", "build", "dist"}


def _package_dirs() -> dict[str, Path]:
    """Import name -> folder of every package of the distribution, found by walking the tree
    (a top-level folder with an ``__init__.py`` is ``fbaconf.<folder>``, its sub-folders with
    one its sub-packages): nothing is hand-listed."""
    out: dict[str, Path] = {}
    for top in sorted(ROOT.iterdir()):
        if (
            not top.is_dir()
            or top.name.startswith((".", "_"))
            or top.name in NOT_INSTALLED
            or not (top / "__init__.py").is_file()
        ):
            continue
        name = "fbaconf" if top.name == "fbaconf" else f"fbaconf.{top.name}"
        for init in sorted(top.rglob("__init__.py")):
            if "__pycache__" in init.parts:
                continue
            rel = init.parent.relative_to(top)
            out[".".join([name, *rel.parts])] = init.parent
    return out


def _modules() -> dict[str, Path]:
    """Import name -> file, for every module of the distribution."""
    out: dict[str, Path] = {}
    for pkg, d in _package_dirs().items():
        for p in sorted(d.glob("*.py")):
            name = pkg if p.name == "__init__.py" else f"{pkg}.{p.stem}"
            out[name] = p
    return out


def _setup_discovery() -> dict[str, str]:
    """What setup.py installs (its package map), read without building anything."""
    import setuptools  # noqa: PLC0415 (build-time tool)

    src = (ROOT / "setup.py").read_text("utf-8")
    ns: dict = {"__file__": str(ROOT / "setup.py"), "__name__": "fbaconf_setup"}
    real = setuptools.setup
    setuptools.setup = lambda **kw: ns.setdefault("_kw", kw)
    try:
        exec(compile(src, "setup.py", "exec"), ns)  # noqa: S102 - setup.py read without building: its own source
    finally:
        setuptools.setup = real
    return ns["_kw"]


def test_the_wheel_installs_every_package_and_its_data():
    kw = _setup_discovery()
    assert {k: str(ROOT / v) for k, v in kw["package_dir"].items()} == {k: str(v) for k, v in _package_dirs().items()}
    assert sorted(kw["packages"]) == sorted(_package_dirs())
    # every non-Python file under a package travels with it (data folders are never forgotten)
    for pkg, d in _package_dirs().items():
        data = set(kw["package_data"].get(pkg, []))
        for f in d.iterdir():
            if f.is_file() and f.suffix not in (".py", ".pyc", ".so", ".o"):
                assert f.name in data, (pkg, f.name)
    # the folders the last wheel forgot
    assert "data/text/comments-crlf.fap" in kw["package_data"]["fbaconf.conformance"]
    assert "fbaconf.mutation.independent" in kw["packages"]


def test_no_python_folder_hides_outside_a_package():
    """A folder of modules without ``__init__.py`` would be left out of the wheel."""
    stray = []
    for _pkg, d in _package_dirs().items():
        for sub in d.iterdir():
            if (
                sub.is_dir()
                and sub.name != "__pycache__"
                and any(sub.glob("*.py"))
                and not (sub / "__init__.py").is_file()
            ):
                stray.append(str(sub.relative_to(ROOT)))
    assert stray == []


def _typing_only(tree: ast.AST) -> set[int]:
    """The ids of the import nodes under ``if TYPE_CHECKING:`` (annotations only: no import at run time)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            out |= {id(n) for b in node.body for n in ast.walk(b)}
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    tree = ast.parse(path.read_text("utf-8"))
    is_pkg = path.name == "__init__.py"
    out = set()
    typing_only = _typing_only(tree)
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = name.split(".")
                keep = len(parts) - node.level + (1 if is_pkg else 0)
                base = ".".join(parts[:keep] + ([base] if base else []))
            targets = [f"{base}.{a.name}" for a in node.names] + ([base] if node.module else [])
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {n: _imports(n, p, mods) for n, p in mods.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, out = set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def _stage(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2])


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules():
    assert _cycles(_graph()) == []


def test_no_import_cycle_between_stages():
    """Stages form layers; only the command-line glue (``*.cli``) may reach across."""
    stages: dict[str, set[str]] = defaultdict(set)
    for mod, deps in _graph().items():
        if mod.endswith(".cli") or mod in ("fbaconf.cli", "fbaconf.__main__"):
            continue
        for d in deps:
            if _stage(d) != _stage(mod):
                stages[_stage(mod)].add(_stage(d))
    assert _cycles(dict(stages)) == []


# The stages from the bottom up (docs/architecture.md says the same, checked below): a stage imports
# only the core and the stages before it (stages grouped in a tuple stand side by side: golden is
# data beside conformance; certification and mutation both rest on the harness); fuzz may fuzz every
# reader below it; generators (run on purpose) may use anything and nothing but the verbs uses them.
LAYERS = (
    "bitstreams",
    "scenes",
    "animation",
    "rendering",
    "reference",
    "profiles",
    ("conformance", "golden"),
    "isolation",
    "harness",
    "explain",
    ("certification", "mutation"),
    "fuzz",
    "generators",
)
CORE = "fbaconf"  # errors, rules, safefs, _atomic and the verb dispatcher (cli, __main__)
GLUE = ("fbaconf.cli", "fbaconf.__main__")


def _rank() -> dict[str, int]:
    return {
        (name if isinstance(names, str) else name): i
        for i, names in enumerate(LAYERS)
        for name in ((names,) if isinstance(names, str) else names)
    }


def _stage_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "fbaconf" and f"fbaconf.{parts[1]}" in _package_dirs() else CORE


def _is_glue(module: str) -> bool:
    return module.endswith(".cli") or module in GLUE


def direction_problems(graph: dict[str, set[str]]) -> list[str]:
    """Every import against the direction rules (the verbs' ``cli`` modules compose stages and are
    exempt from the first two)."""
    rank, out = _rank(), []
    for mod, deps in sorted(graph.items()):
        a = _stage_of(mod)
        for d in sorted(deps):
            b = _stage_of(d)
            if d.endswith(".cli") and not _is_glue(mod):
                out.append(f"{mod} imports the verb module {d} (a library module imports no *.cli)")
            if _is_glue(mod) or a == b:
                continue
            if a == CORE:
                out.append(f"{mod} (the core) imports the stage {b}")
            elif b == "generators":
                out.append(f"{mod} imports generators (run on purpose: only the verbs and tests use them)")
            elif b != CORE and rank[b] >= rank[a]:
                out.append(f"{mod} ({a}) imports {d} ({b}), a stage at or above its own")
    return out


def test_every_stage_has_its_place_in_the_layers():
    stages = {name.split(".")[1] for name in _package_dirs() if name.count(".") == 1}
    assert stages == set(_rank())


def test_imports_go_down_the_layers():
    assert direction_problems(_graph()) == []


def test_the_direction_rules_catch_what_they_name():
    g = {
        "fbaconf.harness.speed.measure": {"fbaconf.generators.models"},
        "fbaconf.reference.pipeline": {"fbaconf.bitstreams.cli"},
        "fbaconf.errors": {"fbaconf.harness.adapters"},
        "fbaconf.bitstreams.decoder": {"fbaconf.harness.adapters"},
        "fbaconf.harness.cli": {"fbaconf.generators.models", "fbaconf.fuzz.engine"},
    }
    got = direction_problems(g)
    assert len(got) == 4 and all("harness.cli" not in x.split()[0] for x in got), got


def test_the_architecture_page_names_the_layers_as_they_are():
    text = (ROOT / "docs" / "architecture.md").read_text("utf-8")
    flat = " → ".join(x if isinstance(x, str) else ", ".join(x) for x in LAYERS[:-1])
    assert f"layers — {flat} —" in " ".join(text.split()), flat


def test_the_readmes_folder_table_is_the_tree():
    """README's "Layout and import names" table lists every stage folder and nothing else."""
    text = (ROOT / "README.md").read_text("utf-8")
    table = text.split("## Layout and import names", 1)[1].split("\n\n", 2)[1]
    listed = {f.strip(" `/") for row in table.splitlines()[2:] for f in row.split("|")[1].split(",")}
    stages = {
        name.split(".")[-1] if name != "fbaconf" else "fbaconf" for name in _package_dirs() if name.count(".") <= 1
    }
    assert listed - {"tests", "benchmarks", "examples"} == stages


_ISSUE = re.compile(r"\b[Ii]ssues? ?#?\d+")


def test_no_code_names_an_issue_number():
    """Comments and docstrings say why, not which issue: a newcomer cannot open the tracker."""
    skip = {".git", ".venv", "build", ".nox", "docs", "node_modules"}
    named = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in ROOT.rglob("*")
        if p.suffix in (".py", ".c", ".h", ".toml", ".sh") and p.is_file() and not skip & set(p.relative_to(ROOT).parts)
        for i, line in enumerate(p.read_text("utf-8", "replace").splitlines(), 1)
        if _ISSUE.search(line)
    ]
    assert named == []


def test_no_module_over_the_size_limit():
    big = {
        str(p.relative_to(ROOT)): n
        for p in _modules().values()
        if (n := len(p.read_text("utf-8").splitlines())) > MAX_LINES
    }
    assert big == {}


# ------------------------------------------------------------------ rule ids
_RULE_ID = re.compile(r"[a-z][a-z0-9]*(-[a-z0-9]+)*")


def _raised_rule_ids() -> dict[str, str]:
    """Rule ids in the source: ``rule="…"`` keywords and the rule argument of the readers'
    ``err``/``error``/``warn`` helpers (second or third positional argument)."""
    found: dict[str, str] = {}
    for path in _modules().values():
        for node in ast.walk(ast.parse(path.read_text("utf-8"))):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            fname = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            cands = [kw.value for kw in node.keywords if kw.arg == "rule"]
            if fname in ("err", "error", "warn", "_err", "fail", "bad"):
                cands += node.args[1:3]
            for c in cands:
                if isinstance(c, ast.Constant) and isinstance(c.value, str) and _RULE_ID.fullmatch(c.value):
                    found.setdefault(c.value, f"{path.relative_to(ROOT)}:{node.lineno}")
                    break
    return found


def test_every_raised_rule_id_is_registered():
    raised = _raised_rule_ids()
    assert len(raised) > 100  # the scan itself works
    missing = {r: where for r, where in raised.items() if r not in RULES}
    assert missing == {}


def test_rule_registry_codes_exist():
    assert all(r.code is None or r.code in CODES for r in RULES.values())


# ------------------------------------------------------------------ references to files
_TOP = (
    "bitstreams",
    "profiles",
    "animation",
    "scenes",
    "rendering",
    "harness",
    "conformance",
    "fuzz",
    "fbaconf",
    "generators",
    "golden",
    "docs",
    "tests",
    "benchmarks",
    "examples",
)
# Files fbaconf writes (not in the tree) and the shared folder beside the checkout.
_PRODUCED = {"statement.md"}
_SHARED = ROOT.parent / "shared"
_SHARED_NAMES = {p.name for p in _SHARED.rglob("*.md")} if _SHARED.is_dir() else set()
_BARE_MD = re.compile(r"(?<![\w./-])([\w-]+\.md)\b")
_PATH = re.compile(r"(?<![\w./-])((?:" + "|".join(_TOP) + r")/[\w./-]*\w\.(?:py|md|toml|csv|json|c|h|css|txt))\b")


def _texts():
    for p in sorted(ROOT.glob("*.md")):
        yield p
    for d in ("docs", "examples", "benchmarks", *(str(p.relative_to(ROOT)) for p in _package_dirs().values())):
        base = ROOT / d
        if base.is_dir():
            for p in sorted(base.rglob("*")):
                if p.suffix in (".md", ".py", ".toml", ".c") and p.is_file() and "__pycache__" not in p.parts:
                    yield p


@pytest.mark.parametrize("doc", [pytest.param(p, id=str(p.relative_to(ROOT))) for p in _texts()])
def test_no_reference_to_a_missing_file(doc: Path):
    text = doc.read_text("utf-8", errors="replace")
    missing = {
        m for m in _PATH.findall(text) if "*" not in m and not (ROOT / m).exists() and not (doc.parent / m).exists()
    }
    missing |= {
        m
        for m in _BARE_MD.findall(text)
        if m not in _PRODUCED
        and m not in _SHARED_NAMES
        and not any((d / m).exists() for d in (ROOT, ROOT / "docs", doc.parent))
    }
    assert sorted(missing) == []


def test_no_test_module_imports_another():
    """Shared helpers live in tests/lib; a test module importing a sibling drags its fixtures and
    module-level work along and breaks when either moves."""
    offenders = []
    for p in sorted((ROOT / "tests").rglob("test_*.py")):
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            offenders += [f"{p.relative_to(ROOT)}: import {n}" for n in names if n.split(".")[0].startswith("test_")]
    assert offenders == [], "\n".join(offenders)


def _where_things_live() -> list[tuple[str, list[str], list[str]]]:
    """(concern, paths, names) per row of docs/architecture.md's "Where things live" table."""
    text = (ROOT / "docs" / "architecture.md").read_text("utf-8")
    table = text.split("## Where things live", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or cells[0] in ("concern", "---") or set(cells[0]) <= {"-"}:
            continue
        paths = re.findall(r"`([\w./*-]+(?:/|\.py|\.toml|\.json|\.c|\.csv))`", cells[1])
        paths += [f"{p}.py" for p in re.findall(r"`([\w./-]+\.py)`/`\.(py)`", cells[1])]
        names = re.findall(r"`([A-Za-z_][\w.]*)`", cells[2])
        rows.append((cells[0], paths, names))
    return rows


def _defined(py: Path) -> set[str]:
    out: set[str] = set()
    tree = ast.parse(py.read_text("utf-8"))
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
            if isinstance(node, ast.ClassDef):
                out |= {
                    f"{node.name}.{n.name}" for n in node.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
                }
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out |= {t.id for t in targets if isinstance(t, ast.Name)}
    return out


def test_the_architecture_table_names_paths_and_names_that_exist():
    """Every path in docs/architecture.md's "Where things live" exists, every name in a row is
    defined in one of that row's modules, and every stage has a row."""
    rows = _where_things_live()
    assert len(rows) > 20
    problems = []
    for concern, paths, names in rows:
        modules: list[Path] = []
        for p in paths:
            found = sorted(ROOT.glob(p)) if "*" in p else [ROOT / p]
            if not found or not all(f.exists() for f in found):
                problems.append(f"{concern}: no {p}")
            for f in found:
                modules += sorted(f.rglob("*.py")) if f.is_dir() else [f] if f.suffix == ".py" else []
        defined = set().union(*(_defined(m) for m in modules if m.exists())) if modules else set()
        problems += [f"{concern}: {n} is defined in none of {paths}" for n in names if modules and n not in defined]
    stages = {p.split("/")[0] for _, paths, _ in rows for p in paths}
    for layer in LAYERS:
        for stage in (layer,) if isinstance(layer, str) else layer:
            if stage not in stages:
                problems.append(f"the stage {stage}/ has no row")
    assert problems == [], "\n".join(problems)
