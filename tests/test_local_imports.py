"""Function-local imports only for heavy dependencies (issue 24, STYLE): an import inside a
function must load something the module should not pay for at import time, so that
``beamrelay --help``, the drivers and the checker start without it. Allowed:

- a heavy third-party package, each listed in :data:`HEAVY` with its one-line reason;
- a module of this repository whose own module-level imports reach one of them
  (transitively; computed here from the sources);
- an import listed in :data:`CYCLE_BREAKERS` (it would close an import cycle at the top);
- any import in a package of :data:`LAZY_PACKAGES` (the CLI's commands), for its reason.

Anything else belongs at the top of its module."""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

from tests.paths import REPO

PACKAGES = ("planner", "schemas", "drivers")
HEAVY = {
    "casadi": "the symbolic beam graph and IPOPT: about 0.3 s to import",
    "pinocchio": "the arm's kinematics (with coal): about 0.5 s",
    "coal": "collision geometry, loaded with pinocchio",
    "open3d": "raycasting and point clouds: about 1 s",
    "scipy": "optimisation and statistics, only where they are used",
    "matplotlib": "plots, only when a figure is written",
    "mpl_toolkits": "3D plot axes, with matplotlib",
    "zenoh": "the bus, not needed to plan or check",
    "cv2": "marker detection, only in the camera paths",
    "viser": "the console's web server",
    "dask": "distributed studies, optional",
    "distributed": "dask's scheduler client, optional",
    "ruckig": "trajectory timing, a compiled extension",
    "pyrealsense2": "the RealSense SDK, absent without a camera",
    "rtde_control": "ur_rtde, absent without a UR",
    "rtde_receive": "ur_rtde, absent without a UR",
    "rtde_io": "ur_rtde, absent without a UR",
    "dashboard_client": "ur_rtde, absent without a UR",
    "mcap": "recordings, only when recording",
    "rosbags": "ROS 2 message types, only with --ros2",
    "ur_analytic_ik": "the UR closed-form IK, a compiled extension",
    "trimesh": "mesh files, only for mesh scene objects",
    "yourdfpy": "URDF meshes, only for the console's robot view",
    "selenium": "browser tests only",
    "websockets": "the console's bench client only",
    "rich": "progress bars and tables: about 0.1 s, only where drawn",
    "orjson": "plan.json writing, only when writing",
    "xxhash": "the console's cache keys only",
    "importlinter": "the architecture check only",
    "resource": "POSIX only (peak memory figures)",
    "fcntl": "POSIX only (advisory file locks)",
}
CYCLE_BREAKERS: dict[tuple[str, str], str] = {}
#: packages whose functions may import anything lazily, with the reason
LAZY_PACKAGES = {
    "planner.cli": "a command loads what it runs when it runs: --help, a typo and the"
    " light commands answer in 0.4 s instead of loading every command's modules",
    "planner.bench": "each benchmark is a command, imported to register it: it loads what"
    " it measures when it runs",
    "planner.studies": "each study is a command, imported to register it: it loads what it"
    " runs when it runs (and in its worker processes)",
}


def _module(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


@cache
def _sources() -> dict[str, Path]:
    return {_module(p): p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")}


def _resolve(name: str) -> str | None:
    """The repository module ``name`` refers to (a module, or a name in a package)."""
    mods = _sources()
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


@cache
def _top_imports(module: str) -> frozenset[str]:
    """What ``module`` imports at module level (not in functions, not TYPE_CHECKING)."""
    tree = ast.parse(_sources()[module].read_text())
    out: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Import):
                out.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                out.add(node.module)
                out.update(f"{node.module}.{a.name}" for a in node.names)
            elif isinstance(node, ast.If) and "TYPE_CHECKING" not in ast.unparse(node.test):
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)

    visit(tree.body)
    return frozenset(out)


@cache
def heavy_reach(module: str) -> str | None:
    """A heavy package ``module`` loads when imported (its own or its package's
    module-level imports, transitively), or None."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        parts = m.split(".")
        chain = [".".join(parts[:i]) for i in range(1, len(parts) + 1)]  # packages first
        for mod in chain:
            if mod not in _sources():
                continue
            for name in _top_imports(mod):
                top = name.split(".")[0]
                if top in HEAVY:
                    return top
                if top in PACKAGES and (r := _resolve(name)) is not None:
                    todo.append(r)
    return None


def local_imports() -> list[tuple[str, int, str]]:
    """(module, line, what it imports) of every import inside a function: a module, or a
    name in a module (``from m import x``: ``m.x``, which may be a submodule)."""
    out = []
    for module, path in sorted(_sources().items()):
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    out += [(module, node.lineno, a.name) for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    out += [(module, node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def why_local(module: str, target: str) -> str | None:
    """The reason the import may stay in a function, or None."""
    for package, why in LAZY_PACKAGES.items():
        if module == package or module.startswith(package + "."):
            return why
    top = target.split(".")[0]
    if top in HEAVY:
        return HEAVY[top]
    if (module, target) in CYCLE_BREAKERS:
        return CYCLE_BREAKERS[(module, target)]
    if top in PACKAGES and (r := _resolve(target)) is not None and (h := heavy_reach(r)):
        return f"loads {h}"
    return None


def test_function_local_imports_are_of_heavy_dependencies_only() -> None:
    bad = [f"{m}:{line} imports {t} in a function; nothing heavy: import it at the top"
           for m, line, t in local_imports() if why_local(m, t) is None]  # fmt: skip
    assert bad == [], "\n".join(bad)


def test_the_reach_follows_module_level_imports() -> None:
    assert heavy_reach("planner.beam.graph") == "casadi"
    assert heavy_reach("planner.model.transforms") is None
    assert why_local("planner.plan.pipeline", "casadi") == HEAVY["casadi"]
    assert why_local("planner.plan.pipeline", "json") is None
    assert why_local("planner.plan.pipeline", "planner.beam.graph.BeamModel") == "loads casadi"
    assert why_local("planner.cli.plan", "json") == LAZY_PACKAGES["planner.cli"]
