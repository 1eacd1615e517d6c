"""The code's shape, checked from its syntax trees: each layer gets its own slice of a protocol, no module
reaches for another's private names."""

from __future__ import annotations

import ast
import functools
import textwrap
from pathlib import Path

import beambench

PACKAGE = Path(beambench.__file__).parent
# below session/: these receive slices (SimSlice, markers, settings), never the whole protocol; acquisition/ is the
# protocol's own home (its schema and step plan)
SLICED = ("backends", "sim", "emulators", "sinks", "devices", "analysis")


def _modules(*packages: str) -> list[Path]:
    roots = [PACKAGE / p for p in packages] if packages else [PACKAGE]
    return sorted(p for root in roots for p in root.rglob("*.py"))


@functools.cache
def _tree(path: Path) -> ast.Module:
    """``path`` parsed once for the whole module (every check reads the same files; none changes a tree)."""
    return ast.parse(path.read_text())


@functools.cache
def _nodes(path: Path) -> tuple[ast.AST, ...]:
    """Every node of ``path``'s tree, in ``ast.walk`` order, listed once."""
    return tuple(ast.walk(_tree(path)))


def _name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports_protocol_model(path: Path) -> bool:
    return any(
        isinstance(node, ast.ImportFrom)
        and node.module == "beambench.acquisition.protocol.schema"
        and any(a.name == "Protocol" for a in node.names)
        for node in _nodes(path)
    )


def test_no_layer_below_session_takes_the_whole_protocol() -> None:
    found = []
    for path in _modules(*SLICED):
        if not _imports_protocol_model(path):
            continue
        for node in _nodes(path):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                args = [*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs]
                found += [
                    f"{_name(path)}.{node.name}({a.arg})"
                    for a in args
                    if a.annotation is not None and "Protocol" in ast.unparse(a.annotation).split(" | ")
                ]
    assert found == []


# modules whose private names their package's siblings share by design (natnet's frame parsers read with wire.py's
# readers); any other leading underscore is private to its module
SHARES_PRIVATE_NAMES = ("beambench.devices.natnet.wire",)


def test_no_module_imports_another_modules_private_names() -> None:
    """A leading underscore is private to its module, except in :data:`SHARES_PRIVATE_NAMES` (then to its package):
    a helper another module needs gets a public name."""
    found = []
    for path in _modules():
        home = _name(path).rsplit(".", 1)[0] if path.name != "__init__.py" else _name(path)
        for node in _nodes(path):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("beambench"):
                module = node.module or ""
                shared = module in SHARES_PRIVATE_NAMES and module.rsplit(".", 1)[0] == home
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
                found += [f"{_name(path)}: {module}.{n}" for n in private if not shared]
    assert found == []


PROBE_FREE = ("backends", "session")  # capabilities are checked with isinstance on a typing.Protocol here


def test_capabilities_are_checked_by_protocol_not_by_probing_attribute_names() -> None:
    found = []
    for path in [*_modules(*PROBE_FREE), PACKAGE / "analysis" / "session_analysis.py"]:
        for node in _nodes(path):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("getattr", "hasattr")
                and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and (node.func.id == "hasattr" or len(node.args) == 3)
            ):
                found.append(f"{_name(path)}:{node.lineno} {ast.unparse(node)}")
    assert found == []


def test_the_device_rig_reads_the_mocaps_echoes_through_its_protocol_not_its_client() -> None:
    reached = [
        ast.unparse(n)
        for n in _nodes(PACKAGE / "backends" / "hardware.py")
        if (isinstance(n, ast.Attribute) and n.attr == "client")
        or (isinstance(n, ast.Constant) and n.value == "client")
    ]
    assert reached == []


MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 100


def test_no_import_cycle_of_any_size_even_inside_a_package() -> None:
    """Strongly connected groups of the import graph (lazy and TYPE_CHECKING imports included): none."""
    import grimp

    graph = grimp.build_graph("beambench")
    edges = {m: graph.find_modules_directly_imported_by(m) for m in graph.modules}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = [stack.pop()]
            while group[-1] != v:
                group.append(stack.pop())
            if len(group) > 1:
                groups.append(sorted(group))

    for module in sorted(graph.modules):
        if module not in index:
            visit(module)
    assert groups == []


def test_modules_and_functions_stay_small() -> None:
    long_modules, long_functions = [], []
    for path in _modules():
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            long_modules.append(f"{_name(path)}: {text.count(chr(10))} lines")
        for node in _nodes(path):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long_functions.append(f"{_name(path)}.{node.name}: {n} lines")
    assert (long_modules, long_functions) == ([], [])


def test_the_calibration_result_is_built_by_keyword_and_its_budget_shares_are_named() -> None:
    import dataclasses

    from beambench.studies.twin_calibration.search import Result

    assert all(f.kw_only for f in dataclasses.fields(Result))
    shares = [
        ast.unparse(n)
        for n in _nodes(PACKAGE / "studies" / "twin_calibration" / "search.py")
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "over"
    ]
    assert shares and all(not isinstance(ast.parse(c).body[0].value.args[0], ast.Constant) for c in shares), shares  # type: ignore[attr-defined]


# getattr with a default probes what a platform or a library may lack (a signal, a C loader, a socket option, an
# exception's optional field); our own objects have typed fields whose defaults are declared once
PROBED = {"signal", "yaml", "socket", "exc", "self._bus"}


def test_no_silent_default_read_of_our_own_objects() -> None:
    found = []
    for path in _modules():
        for node in _nodes(path):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id == "getattr"
                and len(node.args) == 3
                and isinstance(node.args[1], ast.Constant)  # a field by name (a key looked up is another matter)
                and ast.unparse(node.args[0]) not in PROBED
            ):
                found.append(f"{_name(path)}:{node.lineno} {ast.unparse(node)}")
    assert found == []


REPO = PACKAGE.parents[1]
TESTS = REPO / "tests"
IMPORTERS = ("src", "tests", "benchmarks", "docs")  # every place that imports beambench


def _top_level(tree: ast.Module) -> tuple[set[str], dict[str, str]]:
    """The names a module defines and, for each name it imports from beambench, the module it comes from
    (conditional and TYPE_CHECKING blocks included)."""
    defined: set[str] = set()
    imported: dict[str, str] = {}

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                defined.add(node.name)
            elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                defined.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("beambench"):
                imported.update({a.asname or a.name: f"{node.module}.{a.name}" for a in node.names})
            elif isinstance(node, ast.If | ast.Try | ast.With):
                visit(node.body)
                visit(getattr(node, "orelse", []))
                for handler in getattr(node, "handlers", []):
                    visit(handler.body)

    visit(tree.body)
    return defined, imported


def _module_files() -> dict[str, Path]:
    return {_name(p): p for p in _modules()}


def _may_reexport(module: str, path: Path, source: str) -> bool:
    """Only a package's ``__init__`` may offer a name, and only one of its own submodules'."""
    return path.name == "__init__.py" and source.startswith(module + ".")


def test_no_module_re_exports_a_name_it_imports() -> None:
    """``__all__`` and ``import x as x`` offer only the module's own names (a package's: its submodules')."""
    found = []
    for module, path in _module_files().items():
        tree = _tree(path)
        defined, imported = _top_level(tree)
        offered: list[str] = []
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
            ):
                offered += [e.value for e in ast.walk(node.value) if isinstance(e, ast.Constant)]
            if isinstance(node, ast.ImportFrom):
                offered += [a.name for a in node.names if a.asname == a.name]
        found += [
            f"{module}: {name} (from {imported[name]})"
            for name in offered
            if name in imported and name not in defined and not _may_reexport(module, path, imported[name])
        ]
    assert found == []


def _uses(nodes: tuple[ast.AST, ...], files: dict[str, Path]) -> list[tuple[int, str, str]]:
    """(line, module, name) for every ``from beambench.M import N`` and every ``alias.N`` of a module imported as
    ``alias`` (``from beambench.P import M as alias``, ``import beambench.M as alias``)."""
    uses, aliases = [], {}
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module in files:
            for a in node.names:
                if f"{node.module}.{a.name}" in files:
                    aliases[a.asname or a.name] = f"{node.module}.{a.name}"
                else:
                    uses.append((node.lineno, node.module, a.name))
        elif isinstance(node, ast.Import):
            aliases.update({a.asname: a.name for a in node.names if a.asname and a.name in files})
    for node in nodes:
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            uses.append((node.lineno, aliases[node.value.id], node.attr))
    return uses


def test_every_import_names_the_module_a_name_lives_in() -> None:
    """``from beambench.M import N`` and ``M.N`` (in the package, its tests, benchmarks and docs): N is defined in
    M, is a submodule of M, or M is a package offering one of its own submodules' names; never a name M imported."""
    files = _module_files()
    tops = {m: _top_level(_tree(p)) for m, p in files.items()}
    found = []
    for folder in IMPORTERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            for line, module, name in _uses(_nodes(path), files):
                defined, imported = tops[module]
                if name in defined or f"{module}.{name}" in files or name not in imported:
                    continue
                if not _may_reexport(module, files[module], imported[name]):
                    found.append(f"{path.relative_to(REPO)}:{line}: {module}.{name} lives in {imported[name]}")
    assert found == []


CATALOGUES = {PACKAGE / "acquisition" / "protocol" / "scenes.py", PACKAGE / "acquisition" / "protocol" / "backends.py"}


def _catalogue_names() -> set[str]:
    from beambench.acquisition.protocol.backends import BACKEND_INFO
    from beambench.acquisition.protocol.scenes import SCENES

    return set(SCENES) | set(BACKEND_INFO)


def _named_in(node: ast.Compare | ast.MatchValue, names: set[str]) -> list[str]:
    """The catalogue names a comparison spells out: a string literal on either side, or one in the tuple, list or
    set a membership test (``in``) looks in (a whole list compared with ``==`` is a command line, not a name)."""
    if isinstance(node, ast.MatchValue):
        spelled = [node.value]
    else:
        spelled = [node.left]
        for op, right in zip(node.ops, node.comparators):
            if isinstance(op, ast.In | ast.NotIn) and isinstance(right, ast.Tuple | ast.List | ast.Set):
                spelled += right.elts
            else:
                spelled.append(right)
    return [e.value for e in spelled if isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value in names]


def test_no_module_outside_the_catalogues_compares_with_a_rig_or_backend_name() -> None:
    """A rig or backend is asked for its catalogue flags (``scene_info(rig).walks``, ``backend_info(b).devices``),
    never compared with its name (``rig == "walker"``, ``backend in ("sim", "emulated")``, ``case "contact":``):
    a new scene or backend then gets every behaviour its flags call for. Names in messages are not comparisons."""
    names = _catalogue_names()
    assert {"contact", "walker", "release", "sim", "hardware"} <= names  # the check knows what it looks for
    found = []
    for path in _modules():
        if path in CATALOGUES:
            continue
        for node in _nodes(path):
            if isinstance(node, ast.Compare | ast.MatchValue):
                found += [f"{_name(path)}:{node.lineno} {n!r}" for n in _named_in(node, names)]
    assert found == []


FAMILY_REGISTRY = {PACKAGE / "sim" / "models" / "families.py", PACKAGE / "sim" / "models" / "registry.py"}


def _compared_strings(node: ast.Compare) -> list[str]:
    """Every string literal a comparison spells out (either side, or inside the tuple, list or set ``in`` looks in)."""
    spelled = [node.left]
    for op, right in zip(node.ops, node.comparators):
        is_collection = isinstance(right, ast.Tuple | ast.List | ast.Set)
        spelled += right.elts if isinstance(op, ast.In | ast.NotIn) and is_collection else [right]
    return [e.value for e in spelled if isinstance(e, ast.Constant) and isinstance(e.value, str)]


def test_no_module_outside_the_family_registry_compares_with_a_model_name():
    """What a beam model is (joint springs or segments, a walker's leg, the paper's model) is asked of its family
    (``family_of(m).segmented``, ``.walker_leg``, ``PAPER_MODEL``), never read off its name (``m == "prb3"``):
    a newly declared family then gets every behaviour its flags call for."""
    from beambench.sim.models.registry import UnknownModelError, family_of

    def is_model_name(text: str) -> bool:
        try:
            family_of(text)
        except UnknownModelError:
            return False
        return True

    assert all(map(is_model_name, ("prb3", "rod10", "rod3g"))) and not is_model_name("walker")  # the check's premise
    found = []
    for path in _modules():
        if path in FAMILY_REGISTRY:
            continue
        for node in _nodes(path):
            if isinstance(node, ast.Compare):
                found += [f"{_name(path)}:{node.lineno} {s!r}" for s in _compared_strings(node) if is_model_name(s)]
    assert found == []


# optional engines only a few tests run: every xdist worker collects the whole suite, so a test module imports
# them inside its tests or fixtures, never at its top (Dask and PyElastica with numba: about 1 CPU-s a worker)
NOT_AT_COLLECTION = {"dask", "distributed", "elastica", "numba"}


def _collection_time_imports(body: list[ast.stmt]) -> list[tuple[int, str]]:
    """(line, package) of each import a module's top level runs (inside its ``if``/``try``/``with`` blocks too),
    ``pytest.importorskip("x")`` included."""
    found = []
    for node in body:
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            found.append((node.lineno, (node.module or "").split(".")[0]))
        elif isinstance(node, ast.If | ast.Try | ast.With):
            blocks = [node.body, getattr(node, "orelse", []), getattr(node, "finalbody", [])]
            blocks += [h.body for h in getattr(node, "handlers", [])]
            found += [hit for block in blocks for hit in _collection_time_imports(block)]
        for call in ast.walk(node) if isinstance(node, ast.Expr | ast.Assign) else []:
            if (
                isinstance(call, ast.Call)
                and ast.unparse(call.func) == "pytest.importorskip"
                and call.args
                and isinstance(call.args[0], ast.Constant)
            ):
                found.append((node.lineno, str(call.args[0].value).split(".")[0]))
    return found


def test_no_test_module_imports_an_optional_engine_at_collection() -> None:
    found = [
        f"{path.relative_to(REPO)}:{line}: {package}"
        for path in sorted(TESTS.glob("*.py"))
        for line, package in _collection_time_imports(_tree(path).body)
        if package in NOT_AT_COLLECTION
    ]
    assert found == []


# A test's own stand-in may hold a private name that one of beambench's objects also has: expression as written in
# its test module → why it is the test's own
OWN_PRIVATES = {
    ("test_odrive_usb.py", "odrv._log"): "the USB ODrive stand-in (a test class) logs the properties written to it",
    ("test_odrive_usb.py", "stuck._log"): "a stand-in axis of that test shares the stand-in device's log",
    ("test_disk_full.py", "w._tables"): "the writer's steps table, mid-write: not yet observed through the file",
}


def _is_private(name: str) -> bool:
    return len(name) > 1 and name.startswith("_") and not name.startswith("__")


@functools.cache
def _beambench_private_names() -> frozenset[str]:
    """Every private name beambench defines: attributes it assigns (``self._x = …``), functions, methods and
    classes, module- and class-level names (a superset: locals too)."""
    names: set[str] = set()
    for path in _modules():
        for node in _nodes(path):
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
    return frozenset(filter(_is_private, names))


def _foreign_names(tree: ast.AST) -> set[str]:
    """The names a module binds by importing from outside beambench (``os``, ``np``, ``sleep`` …)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.asname or a.name.split(".")[0] for a in node.names if not a.name.startswith("beambench")}
        elif isinstance(node, ast.ImportFrom) and not (node.module or "").startswith("beambench"):
            names |= {a.asname or a.name for a in node.names}
    return names


def _root(node: ast.expr) -> ast.expr:
    """The name an expression such as ``rig.mocap.client._cmd`` or ``f(x)._y[0]._z`` starts from (``super()``
    stands for ``self``)."""
    while isinstance(node, ast.Attribute | ast.Subscript | ast.Call):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "super":
            return ast.Name("self")
        node = node.func if isinstance(node, ast.Call) else node.value
    return node


def _private_reaches(tree: ast.AST, private: frozenset[str]) -> list[tuple[int, str]]:
    """(line, expression) of each ``x._name`` (and ``getattr``/``setattr``/``hasattr`` of ``"_name"``) where
    ``_name`` is one of beambench's private names and ``x`` is not ``self``/``cls``/``super()`` (a class's own, or
    its base's, in a subclass a test defines) or imported from elsewhere."""
    foreign = _foreign_names(tree) | {"self", "cls"}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in private:
            root = _root(node.value)
            if not (isinstance(root, ast.Name) and root.id in foreign):
                found.append((node.lineno, ast.unparse(node)))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("getattr", "setattr", "hasattr")
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and node.args[1].value in private
        ):
            found.append((node.lineno, ast.unparse(node)))
    return found


def _code_strings(tree: ast.AST) -> list[tuple[int, ast.Module]]:
    """The string literals of several lines that parse as Python (scripts a test runs in a child), parsed."""
    parsed = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and "\n" in node.value.strip():
            try:
                parsed.append((node.lineno, ast.parse(textwrap.dedent(node.value))))
            except SyntaxError:
                continue
    return parsed


def private_reaches(path: Path) -> list[str]:
    """``file:line expression`` of each reach into a beambench private name in one test module, in its own code
    and in the code strings it runs, less :data:`OWN_PRIVATES`."""
    private = _beambench_private_names()
    tree = _tree(path)
    found = [(line, expr, "") for line, expr in _private_reaches(tree, private)]
    for line, inner in _code_strings(tree):
        found += [(line, expr, f" (code string, its line {n})") for n, expr in _private_reaches(inner, private)]
    kept = sorted(hit for hit in found if (path.name, hit[1]) not in OWN_PRIVATES)
    return [f"{path.name}:{line} {expr}{where}" for line, expr, where in kept]


def test_no_test_reaches_into_a_private_attribute_of_beambench() -> None:
    """A test observes a driver through what a user has: the socket it talks to, a public property, the file, the
    wire; never ``rig.mocap.client._cmd``. Its own stand-ins' private names are listed in :data:`OWN_PRIVATES`."""
    files = sorted(TESTS.glob("*.py"))
    assert len(files) > 50
    files.remove(Path(__file__).resolve())  # its probe spells private reaches on purpose
    found = [hit for path in files for hit in private_reaches(path)]
    assert found == []


def test_the_private_reach_check_finds_each_spelling(tmp_path: Path) -> None:
    """The checker itself: attribute chains, module privates, ``getattr`` by name and code strings are found;
    ``self``/``super()``, names imported from elsewhere, names beambench does not define and allow-listed stand-ins
    pass."""
    assert {"_cmd", "_ser", "_MESSAGES", "_idle_sent_ns", "_log"} <= _beambench_private_names()
    assert "_not_a_beambench_name" not in _beambench_private_names()
    code = (
        "import os\nfrom beambench.devices.natnet import protocol as nn\n"
        "class Peer:\n    def f(self):\n        return self._cmd, super()._command\n"
        "def g(rig, lc, odrv):\n    rig.mocap.client._cmd.getsockname()\n    os._exit(0)\n    nn._MESSAGES\n"
        "    getattr(lc, '_ser')\n    rig._not_a_beambench_name\n    rig.__dict__\n    odrv._log\n"
        "SCRIPT = 'x = 1\\nmotor._idle_sent_ns\\n'\n"
        "PROSE = 'reads client._cmd\\nand more'\n"
    )
    probe = tmp_path / "test_probe.py"
    probe.write_text(code)
    assert private_reaches(probe) == [
        "test_probe.py:7 rig.mocap.client._cmd",
        "test_probe.py:9 nn._MESSAGES",
        "test_probe.py:10 getattr(lc, '_ser')",
        "test_probe.py:13 odrv._log",
        "test_probe.py:14 motor._idle_sent_ns (code string, its line 2)",
    ]
    allowed = tmp_path / "test_odrive_usb.py"  # the same line in the module whose stand-in it is: allowed
    allowed.write_text("def g(odrv):\n    return odrv._log\n")
    assert private_reaches(allowed) == []
