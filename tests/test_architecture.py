"""The import graph of the project, read from the source with ``ast`` (nothing is imported).

The pipeline's stages are packages, and the design folder is the only contract between
them (``docs/for-contributors.md``, ``docs/design-folder.md``).  These tests keep it so:

* no import cycle among the project's modules (a submodule import also counts as an import
  of every enclosing package, whose ``__init__`` runs first, except the importer's own);
* every import runs from a stage to itself or to a lower layer (:data:`LAYERS`);
* the shell's mechanics (:mod:`pysolver.mechanics`: model, membrane energy and mesh, Newton
  solver, rim margin) sit just above the core, below both the simulator and temporal
  programming, which share them;
* the simulator (``sim``) imports nothing from ``pysolver`` but the core (table reader,
  ``params``, ``errors``, ``core``, ``geometry``), the mechanics and the runtime material
  model;
* of ``pysolver``, only the gateway :mod:`pysolver.simulator` imports ``sim``; the other
  front ends (the build and its stage runners, the refinement, studio, tolerance analysis,
  sweep, the command line) reach the simulator through it, and no design-side package
  (design, temporal, render, material, fitting, mechanics, core) imports ``sim`` at all;
* the stencil search (:mod:`pysolver.design.stencil`) is a package inside the design stage:
  its modules import, of the rest of the design stage, only the steps below it (flattening,
  layout, time landscape), and every other module reaches it through the names its
  ``__init__`` exports, never through one of its modules;
* the offline fitting tools (:mod:`pysolver.fitting`: material fit and report, membrane-model
  fit) sit above every runtime stage: only the command line imports them;
* project modules are imported at module level: an import inside a function hides an edge
  of the graph.  The one exception is the command line (the package :mod:`pysolver.cli`:
  its subcommands, :mod:`pysolver.cli.commands`), whose subcommands import their stage when
  they run so that ``morphshell --help`` is instant; every such import carries a
  ``# lazy:`` comment;
* the command line is the top of the graph: no module outside :mod:`pysolver.cli` imports
  it (the build, the studio and the tools read the stage table, :mod:`pysolver.stages`,
  which lives outside the package for that reason);
* the pipeline's table (:mod:`pysolver.stages`) and the command line's
  (:mod:`pysolver.cli.table`) name their runners as ``"module:function"`` strings, imported
  when they run: each name is an edge of the graph too (from the orchestrator
  :mod:`pysolver.build` for the stages, from :mod:`pysolver.cli` for the subcommands),
  checked like the imports, and every name exists;
* any other import inside a function (an optional or heavy third-party dependency) carries a
  comment saying why (a bare ``# noqa`` is not a reason).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP_PACKAGES = ("pysolver", "sim")

# Layers, lowest first: a module may import its own group and any group of a lower rank.
LAYERS = {
    "core": 0,        # errors, params, the plumbing package core (manifest, writes, locks,
                      # ownership, staging, inputs, child: argv of child Pythons, machine:
                      # memory left, progress lines, JSON records, provenance), geometry,
                      # tables: used by every stage
    "mechanics": 1,   # shell model, membrane energy and mesh, Newton solver, rim margin
    "material": 1,    # runtime bracket material model
    "design": 2,      # target surface -> stencil -> layout -> design tables, model.npz
    "sim": 2,         # the simulator: reads the design folder only
    "report": 3,      # simulation report, scan comparison, viewer data
    "temporal": 3,    # temporal programming; uses the mechanics' membrane, not the simulator
    "render": 3,      # OpenSCAD part files and STLs
    "fitting": 3.5,   # offline fitting tools (material fit and its report, membrane-model
                      # fit): above every runtime stage, so none of them imports a fit
    "front": 4,       # orchestrator (build, stages table and runners, refine), the gateway
                      # to the simulator, command line, studio, sweep, tolerance, coupon
}

CORE = {"pysolver", "pysolver.errors", "pysolver.params", "pysolver.core", "pysolver.geometry",
        "pysolver.tables"}  # and every module of pysolver.params and pysolver.core
FITTING = ("pysolver.fitting", "pysolver.fitting.material_fit",
           "pysolver.fitting.material_report", "pysolver.fitting.membrane_fit",
           "pysolver.fitting.cell_membrane")
CLI = "pysolver.cli"  # the command line's package
LAZY_ALLOWED = {CLI, "pysolver.cli.commands"}  # the command line: see the docstring


def group(mod: str) -> str:
    """The layer group of a project module (the settings package ``pysolver.params`` and its
    topic modules are all core)."""
    if mod in CORE or mod.startswith(("pysolver.params.", "pysolver.core.")):
        return "core"
    for prefix, g in (("pysolver.fitting", "fitting"), ("pysolver.material", "material"),
                      ("pysolver.design", "design"),
                      ("pysolver.mechanics", "mechanics"),
                      ("pysolver.temporal", "temporal"), ("pysolver.render", "render"),
                      ("sim.report", "report"), ("sim.viewer", "report"),
                      ("sim.model", "sim")):
        if mod == prefix or mod.startswith(prefix + "."):
            return g
    if mod == "sim":
        return "sim"
    return "front"


def project_modules() -> dict[str, Path]:
    mods = {}
    for top in TOP_PACKAGES:
        for p in sorted((ROOT / top).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = p
    return mods


MODULES = project_modules()


def _resolve(mod: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module
    base = mod.split(".")
    if path.name != "__init__.py":
        base = base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _with_parents(name: str) -> list[str]:
    """``a.b.c`` -> the project modules ``a``, ``a.b``, ``a.b.c`` that exist."""
    parts = name.split(".")
    return [m for m in (".".join(parts[:i]) for i in range(1, len(parts) + 1)) if m in MODULES]


def _module_level(tree: ast.Module) -> set[int]:
    """ids of the module-level statements (those under a module-level if/try count too)."""
    top = {id(n) for n in tree.body}
    for n in tree.body:
        if isinstance(n, (ast.If, ast.Try)):
            top |= {id(c) for c in ast.walk(n)}
    return top


def _import_nodes():
    """(module, path, source lines, import node, nested) for every import statement."""
    for mod, path in MODULES.items():
        src = path.read_text()
        tree = ast.parse(src)
        top_level = _module_level(tree)
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                yield mod, path, src.splitlines(), node, id(node) not in top_level


def imports() -> list[tuple[str, str, int, bool, str]]:
    """Every project import: (importer, imported, line, nested, source line)."""
    out = []
    for mod, path, lines, node, nested in _import_nodes():
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            base = _resolve(mod, path, node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                       for a in node.names]
        for t in targets:
            for m in _with_parents(t):
                # (a module's own enclosing packages are initialised before it runs)
                if m != mod and not mod.startswith(m + "."):
                    out.append((mod, m, node.lineno, nested, lines[node.lineno - 1]))
    return out


RUNNER = re.compile(r"^((?:pysolver|sim)(?:\.\w+)*):(\w+)$")


TABLES = {"pysolver.stages": "pysolver.build", "pysolver.cli.table": CLI}
"""The modules that name runners, and the module that imports and runs them."""


def runner_names() -> list[tuple[str, str, str, int, str]]:
    """The ``"module:function"`` names of the tables: (caller, module, function, line,
    table); the caller is the module that imports and runs them."""
    out = []
    for table, caller in TABLES.items():
        path = MODULES[table]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                m = RUNNER.match(node.value)
                if m:
                    out.append((caller, m.group(1), m.group(2), node.lineno, table))
    return out


RUNNERS = runner_names()
IMPORTS = imports() + [(caller, mod, line, False, f"{table}:{line} runner {mod}:{fn}")
                       for caller, mod, fn, line, table in RUNNERS if mod in MODULES]


def test_every_import_is_resolved():
    assert MODULES, "no project modules found"
    assert len(IMPORTS) > 100  # the parser sees the graph (a guard against a silent no-op)


def test_no_import_cycle():
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for a, b, *_ in IMPORTS:
        graph[a].add(b)
    # Tarjan's strongly connected components
    index, low, stack, on, sccs = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not sccs, "import cycles: " + "; ".join(" <-> ".join(c) for c in sccs)


def test_imports_run_downward():
    bad = []
    for a, b, line, _, text in IMPORTS:
        ga, gb = group(a), group(b)
        if ga != gb and LAYERS[gb] >= LAYERS[ga]:
            bad.append(f"{a}:{line} ({ga}) imports {b} ({gb}): {text.strip()}")
    assert not bad, "imports from a lower layer to a higher one:\n" + "\n".join(bad)


def test_sim_reads_only_the_contract():
    allowed = {"core", "mechanics", "material", "sim", "report"}
    bad = [f"{a}:{line} imports {b}: {text.strip()}" for a, b, line, _, text in IMPORTS
           if a.split(".")[0] == "sim" and group(b) not in allowed]
    assert not bad, "sim imports more of pysolver than the design-folder contract:\n" + \
        "\n".join(bad)


SIM_IMPORTERS = {"pysolver.simulator"}  # the one gateway


def test_the_stage_table_names_functions_that_exist():
    """Every runner the stage table names is a module-level function of an existing
    module (read from the source: nothing is imported)."""
    assert len(RUNNERS) >= 8  # the stages and the commands: the parser sees the table
    bad = []
    for _caller, mod, fn, line, table in RUNNERS:
        defs = ({n.name for n in ast.parse(MODULES[mod].read_text()).body
                 if isinstance(n, ast.FunctionDef)} if mod in MODULES else set())
        if fn not in defs:
            bad.append(f"{table}:{line}: {mod}:{fn}")
    assert not bad, "the stage table names functions that do not exist:\n" + "\n".join(bad)


def test_only_the_gateway_imports_sim():
    """Data flows forward: of ``pysolver``, only the gateway :mod:`pysolver.simulator`
    imports the simulator (any ``sim`` module, report and viewer included); design-side
    packages (temporal programming included, whose membrane model uses
    :mod:`pysolver.mechanics`) and the front ends never do."""
    assert SIM_IMPORTERS <= set(MODULES)
    bad = [f"{a}:{line} ({group(a)}) imports {b}" for a, b, line, _, _ in IMPORTS
           if a.split(".")[0] == "pysolver" and a not in SIM_IMPORTERS
           and b.split(".")[0] == "sim"]
    assert not bad, "\n".join(bad)


def test_both_tables_name_their_runners():
    """The parser sees the runner names of the stage table and of the command line's."""
    assert {table for *_, table in RUNNERS} == set(TABLES)
    assert all(caller == CLI for caller, mod, *_ in RUNNERS if mod.startswith(CLI + "."))


def test_nothing_imports_the_command_line():
    """The command line is the top of the graph: only its own package imports it (the
    build it runs, the studio and the tools read :mod:`pysolver.stages` instead)."""
    assert CLI in MODULES and f"{CLI}.commands" in MODULES
    bad = [f"{a}:{line} imports {b}" for a, b, line, _, _ in IMPORTS
           if (b == CLI or b.startswith(CLI + ".")) and not (a == CLI or a.startswith(CLI + "."))]
    assert not bad, "\n".join(bad)


def top_level() -> set[str]:
    """The modules (``build.py``) and packages (``cli/``) at the top of ``pysolver``."""
    top = ROOT / "pysolver"
    return ({p.name for p in top.glob("*.py") if p.name != "__init__.py"}
            | {p.name + "/" for p in top.iterdir() if (p / "__init__.py").is_file()})


def test_the_map_names_every_top_level_module():
    """``docs/for-contributors.md``'s map places every module and package at the top of
    ``pysolver`` in its layer: a new one is placed there (or moved into a package) when it
    is added.  The map writes a package as `` `pysolver/cli/` `` or `` `cli/` `` and a
    module as `` `build.py` ``."""
    text = (ROOT / "docs" / "for-contributors.md").read_text(encoding="utf-8")
    table = text[text.index("## Map"):text.index("## Where to change")]
    named = set(re.findall(r"`(?:pysolver/)?([\w]+(?:\.py|/))`", table))
    tops = top_level()
    assert {"build.py", "cli/", "core/", "stages/"} <= tops  # the glob sees the tree
    assert not tops - named, f"top-level modules the map does not name: {sorted(tops - named)}"


def test_project_imports_at_module_level():
    bad = [f"{a}:{line}: {text.strip()}" for a, b, line, nested, text in IMPORTS
           if nested and not (a in LAZY_ALLOWED and "# lazy:" in text)]
    assert not bad, ("project imports inside functions hide edges of the graph; move them to "
                     "module level:\n" + "\n".join(sorted(set(bad))))


def test_runtime_does_not_import_the_offline_fits():
    """The offline fitting tools (material fit, membrane-model fit) live apart from the
    runtime models, in :mod:`pysolver.fitting` and nowhere else: only the command line
    imports them (its fit subcommands), so no runtime stage or front end loads them."""
    assert {m for m in MODULES if group(m) == "fitting"} == set(FITTING)
    for old in ("pysolver.material.fit", "pysolver.material.report",
                "pysolver.temporal.membrane_fit", "pysolver.temporal.cell_membrane"):
        assert old not in MODULES, f"{old}: offline fits live in pysolver.fitting"
    bad = [f"{a}:{line} ({group(a)}) imports {b}" for a, b, line, _, _ in IMPORTS
           if group(b) == "fitting" and group(a) != "fitting" and a not in LAZY_ALLOWED]
    assert not bad, "\n".join(bad)


STENCIL_PKG = "pysolver.design.stencil"
# what the stencil search may use of the rest of the design stage: the steps below it
STENCIL_USES = {"pysolver.design", "pysolver.design.flatten", "pysolver.design.layout",
                "pysolver.design.time_landscape"}


def _in_stencil(mod: str) -> bool:
    return mod == STENCIL_PKG or mod.startswith(STENCIL_PKG + ".")


def test_the_stencil_search_is_a_package_with_one_front():
    """The stencil search sits between the design stage's lower steps and its pipeline: it
    imports only those steps of the design stage, and no module outside it imports one of its
    modules (only the package, whose ``__init__`` names the entry points)."""
    inside = {m for m in MODULES if _in_stencil(m)}
    assert {f"{STENCIL_PKG}.{m}" for m in ("remesh", "optimise", "objective", "candidates",
                                            "count_search", "search", "feasibility",
                                            "alternatives")} <= inside
    down = [f"{a}:{line} imports {b}" for a, b, line, _, _ in IMPORTS
            if _in_stencil(a) and group(b) == "design" and not _in_stencil(b)
            and b not in STENCIL_USES]
    assert not down, "the stencil search imports the design stage above it:\n" + "\n".join(down)
    through = [f"{a}:{line} imports {b}" for a, b, line, _, _ in IMPORTS
               if not _in_stencil(a) and b.startswith(STENCIL_PKG + ".")]
    assert not through, ("import the stencil search's entry points from pysolver.design.stencil, "
                         "not its modules:\n" + "\n".join(through))


def test_layer_table_knows_every_module():
    assert {group(m) for m in MODULES} <= set(LAYERS)


def test_settings_import_only_the_core():
    """The settings package is the bottom of the graph: its topic modules import one another
    and :mod:`pysolver.errors`, nothing else of the project."""
    params = {m for m in MODULES if m == "pysolver.params" or m.startswith("pysolver.params.")}
    assert len(params) > 5, "pysolver.params is a package of topic modules"
    bad = [f"{a}:{line} imports {b}" for a, b, line, _, _ in IMPORTS
           if a in params and b not in params | {"pysolver", "pysolver.errors"}]
    assert not bad, "\n".join(bad)


_NOQA = re.compile(r"noqa(:\s*[A-Z]+[0-9]+(\s*,\s*[A-Z]+[0-9]+)*)?")


def says_why(text: str) -> bool:
    """Some comment in ``text`` gives a reason: words, not only a linter pragma."""
    comments = [line.split("#", 1)[1] for line in text.splitlines() if "#" in line]
    return any(re.search(r"[A-Za-z]{3}", _NOQA.sub("", c)) for c in comments)


def test_says_why_wants_words():
    assert says_why("import x  # heavy: x loads only for STL work")
    assert says_why("# optional: a browser only for screenshots\nimport x")
    assert says_why("import x  # noqa: F401  (optional, probed)")
    assert not says_why("import x  # noqa: F401")
    assert not says_why("import x  # noqa")
    assert not says_why("import x")


def test_function_level_imports_say_why():
    """Any other import inside a function is an optional or heavy dependency, with a comment
    (not only a linter pragma such as ``# noqa: F401``) saying why it is not at module level."""
    bad = []
    for mod, _, lines, node, nested in _import_nodes():
        text = "\n".join(lines[node.lineno - 2:node.end_lineno])  # the line above too
        if nested and not says_why(text):
            bad.append(f"{mod}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    assert not bad, "function-level imports without a reason:\n" + "\n".join(bad)
