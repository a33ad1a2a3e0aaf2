"""The house rules of docs/architecture.md ("Never"), checked on the source.

Every module of every room is parsed with ``ast`` and all its imports are collected, including
those inside functions and relative ones, so a lazy import cannot hide a dependency. A fresh
interpreter then reads a dataset (DN image, truth, observation) and must not load the renderer,
Mitsuba or Dr.Jit.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROOMS = ("infra", "scenes", "renderer", "datasets", "pipeline", "calibration", "service")
CLI_PACKAGE = "skynav"

# File-format libraries: the renderer returns frames in memory; writers and readers live in datasets.
FILE_FORMAT_LIBRARIES = ("PIL", "OpenEXR", "Imath", "imageio", "tifffile", "h5py", "cv2", "png", "skimage.io",
                         "astropy.io.fits", "fitsio")

# Known file access inside the renderer that is not frame I/O, each with its reason. The test fails
# if an entry is no longer needed, so the list cannot go stale.
RENDERER_FILE_ACCESS_ALLOWED = {
    ("renderer/jit_backend.py", "call json.dump"): "the LLVM probe cache (one JSON in the user cache folder)",
    ("renderer/jit_backend.py", "call tempfile.mkstemp"): "the probe cache's atomic write",
    ("renderer/jit_backend.py", "call os.fdopen"): "the probe cache's atomic write",
}


def _package_dirs() -> dict:
    """{import package: folder} from pyproject.toml (the mapping the install uses)."""
    with open(REPO / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]["package-dir"]


def _modules():
    """(import name, path relative to the repo, source) of every module of the rooms and the CLI."""
    out = []
    for package, folder in _package_dirs().items():
        for path in sorted((REPO / folder).glob("*.py")):
            name = package if path.stem == "__init__" else f"{package}.{path.stem}"
            out.append((name, path.relative_to(REPO).as_posix(), path.read_text(encoding="utf-8")))
    return out


def imports_of(source: str, module: str, *, is_package: bool = False) -> set:
    """Absolute names of everything ``source`` imports, at any depth (functions, branches).

    ``from a.b import c`` gives both ``a.b`` and ``a.b.c`` (c may be a module); relative imports
    are resolved against ``module``.
    """
    package = module if is_package else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{base}.{node.module}" if node.module else base
            else:
                base = node.module
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                names.add(node.args[0].value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                target = node.args[0].value
                names.add(f"{package}{target}" if target.startswith(".") else target)
    return names


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def _room_of(name: str):
    for room in ROOMS:
        if _within(name, f"skynav.{room}"):
            return room
    return None


def _is_cli(name: str) -> bool:
    """The command line package itself (``skynav``, ``skynav.cli*``, ``skynav.__main__``), not a room."""
    return _within(name, CLI_PACKAGE) and _room_of(name) is None


@pytest.fixture(scope="module")
def graph():
    mods = _modules()
    g = {}
    for name, rel, src in mods:
        g[name] = (rel, imports_of(src, name, is_package=rel.endswith("__init__.py")))
    return g


def test_the_walker_sees_lazy_relative_and_dynamic_imports():
    src = textwrap.dedent("""
        import numpy as np
        from . import layout
        from .errors import DatasetError
        def f():
            from skynav.renderer.render import render
            if True:
                import mitsuba
        class C:
            def g(self):
                return __import__("drjit")
        def h():
            import importlib
            return importlib.import_module(".runner", "skynav.datasets")
    """)
    got = imports_of(src, "skynav.datasets.reader")
    assert {"numpy", "skynav.datasets", "skynav.datasets.layout", "skynav.datasets.errors",
            "skynav.datasets.errors.DatasetError", "skynav.renderer.render", "mitsuba", "drjit"} <= got
    assert imports_of("from .. import scenes", "skynav.datasets.x") == {"skynav", "skynav.scenes"}
    assert "skynav.datasets.frame_files" in imports_of("from .frame_files import read_png", "skynav.datasets",
                                                       is_package=True)


def test_the_walk_covers_every_room(graph):
    rooms = {_room_of(n) for n in graph} - {None}
    assert rooms == set(ROOMS)
    assert any(_is_cli(n) for n in graph)
    # known edges (one lazy, inside a function) prove the walk is not vacuous
    assert "skynav.renderer.render" in graph["skynav.datasets.runner"][1]
    assert "skynav.scenes.scene" in graph["skynav.renderer.render"][1]


def test_infra_imports_no_room(graph):
    """The infrastructure is the house's floor: every room may import it, it imports none."""
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) == "infra"
           for n in names if _room_of(n) not in (None, "infra") or (_within(n, CLI_PACKAGE) and _room_of(n) is None)]
    assert bad == []
    assert any(_room_of(n) == "infra" for m, (_, names) in graph.items() if _room_of(m) == "scenes" for n in names)


def test_scenes_imports_no_other_room(graph):
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) == "scenes"
           for n in names if (_room_of(n) not in (None, "infra", "scenes")) or _is_cli(n) and n != CLI_PACKAGE]
    assert bad == []


def test_renderer_imports_only_scenes(graph):
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) == "renderer"
           for n in names if _room_of(n) not in (None, "infra", "scenes", "renderer") or (_is_cli(n) and n != CLI_PACKAGE)]
    assert bad == []


def _infra_names() -> dict:
    """{name: module} of everything the infrastructure's modules define at top level."""
    out = {}
    for path in sorted((REPO / "infra").glob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                out[node.name] = f"skynav.infra.{path.stem}"
            elif isinstance(node, ast.Assign):
                out.update({t.id: f"skynav.infra.{path.stem}" for t in node.targets if isinstance(t, ast.Name)})
    out.pop("__all__", None)
    return out


def test_infrastructure_has_one_address(graph):
    """A name of the infrastructure is imported from its home, never through another module
    that imported it (no re-export shims: ``atomic_write_bytes`` is not also a name of
    ``frame_files``). The rooms' packages may list skynav's own errors in their public API (the
    errors module of a room subclasses them)."""
    names = _infra_names()
    assert {"atomic_write_bytes", "process_pool_map", "WarmHeap", "thread_budget", "cap_count"} <= set(names)
    bad = []
    for m, (rel, imported) in graph.items():
        for n in imported:
            module, _, name = n.rpartition(".")
            if name in names and module != names[name] and module in graph and not _within(module, "skynav.infra"):
                bad.append((rel, n))
    assert bad == []


def _renderer_file_access(graph) -> set:
    found = set()
    for m, (rel, names) in graph.items():
        if _room_of(m) != "renderer":
            continue
        for lib in FILE_FORMAT_LIBRARIES:
            if any(_within(n, lib) for n in names):
                found.add((rel, f"import {lib}"))
        tree = ast.parse((REPO / rel).read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            dotted = f"{f.value.id}.{f.attr}" if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else None
            attr = f.attr if isinstance(f, ast.Attribute) else None
            if dotted in ("json.dump", "pickle.dump", "tempfile.mkstemp", "tempfile.NamedTemporaryFile",
                          "os.fdopen", "np.save", "np.savez", "np.savez_compressed", "numpy.save"):
                found.add((rel, f"call {dotted}"))
            elif attr in ("write_bytes", "write_text", "tofile", "writeto", "imwrite"):
                found.add((rel, f"call .{attr}"))
            elif isinstance(f, ast.Name) and f.id == "open":
                mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
                if mode is not None and not (isinstance(mode, ast.Constant) and set(str(mode.value)) <= set("rbt")):
                    found.add((rel, "call open for writing"))
    return found


def test_renderer_does_no_file_io(graph):
    found = _renderer_file_access(graph)
    unexpected = sorted(found - set(RENDERER_FILE_ACCESS_ALLOWED))
    stale = sorted(set(RENDERER_FILE_ACCESS_ALLOWED) - found)
    assert unexpected == [], "the renderer returns frames in memory; file formats live in skynav.datasets"
    assert stale == [], "remove allow-list entries the renderer no longer needs"


def test_pipeline_never_imports_renderer_or_calibration(graph):
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) == "pipeline"
           for n in names if _room_of(n) in ("renderer", "calibration")]
    assert bad == []


def test_datasets_never_import_calibration_and_calibration_never_imports_pipeline(graph):
    """The house plan's flow: datasets sit below the bench's calibration (the bench's own files,
    patterns and captures, are calibration's: skynav.calibration.bench_files, which writes them with
    the datasets' formats), and calibration never reaches the navigation software."""
    bad = [(rel, n) for m, (rel, names) in graph.items()
           for n in names if (_room_of(m), _room_of(n)) in (("datasets", "calibration"), ("calibration", "pipeline"))]
    assert bad == []


# What of skynav.datasets the pipeline may import: the reader and its observation view; the typed
# truth only from scoring modules (docs/architecture.md: ground truth enters only in scoring).
PIPELINE_DATASETS_MODULES = ("skynav.datasets.reader", "skynav.datasets.observation", "skynav.datasets.errors")
PIPELINE_PACKAGE_MEMBERS = {"open", "open_dataset", "Dataset", "Observation", "CalibrationErrorModel", "DatasetError",
                            "FrameIndexError", "IncompleteDatasetError", "reader", "observation", "errors"}
PIPELINE_SCORING_ONLY = ("skynav.datasets.frame_truth", "skynav.datasets.FrameTruth", "skynav.datasets.BodyTruth")


def pipeline_may_import(name: str, *, scoring: bool) -> bool:
    """Whether a pipeline module (a scoring one if ``scoring``) may import ``name`` of datasets."""
    if name == "skynav.datasets" or name in PIPELINE_DATASETS_MODULES:
        return True
    parent, _, member = name.rpartition(".")
    if parent in PIPELINE_DATASETS_MODULES or (parent == "skynav.datasets" and member in PIPELINE_PACKAGE_MEMBERS):
        return True
    return scoring and any(_within(name, a) for a in PIPELINE_SCORING_ONLY)


def test_the_pipeline_rule_itself():
    assert pipeline_may_import("skynav.datasets.observation.Observation", scoring=False)
    assert pipeline_may_import("skynav.datasets.open", scoring=False)
    for internal in ("skynav.datasets.runner", "skynav.datasets.frame_files", "skynav.datasets.truth_schema",
                     "skynav.datasets.generate", "skynav.datasets.frame_truth.FrameTruth"):
        assert not pipeline_may_import(internal, scoring=False), internal
    assert pipeline_may_import("skynav.datasets.frame_truth.FrameTruth", scoring=True)


def test_pipeline_reads_datasets_only_through_the_reader(graph):
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) == "pipeline"
           for n in names if _room_of(n) == "datasets"
           and not pipeline_may_import(n, scoring=m.rsplit(".", 1)[-1].startswith("scor"))]
    assert bad == []


def test_nothing_imports_the_command_line_package(graph):
    # ``import skynav.scenes`` runs skynav/__init__.py, which is only a version string; what is
    # refused is naming the CLI itself (skynav.cli, skynav.cli_dataset, skynav.__main__, skynav.__version__).
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) is not None
           for n in names if _is_cli(n) and n != CLI_PACKAGE]
    assert bad == []


def test_no_script_imports_the_command_line():
    """The benchmarks and examples call the rooms (override parsing is
    :mod:`skynav.scenes.overrides`), never ``skynav.cli*``: the command line is a leaf."""
    bad = []
    for folder in ("benchmarks", "docs"):
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            names = imports_of(path.read_text(encoding="utf-8"), f"{folder}.{path.stem}")
            bad += [(rel, n) for n in names if _is_cli(n) and n != CLI_PACKAGE]
    assert bad == []


def test_nothing_but_the_command_line_imports_the_service(graph):
    """docs/architecture.md: nothing imports ``service`` except the command line (programs outside
    skynav reach it through its client)."""
    bad = [(rel, n) for m, (rel, names) in graph.items() if _room_of(m) not in (None, "service")
           for n in names if _room_of(n) == "service"]
    assert bad == []
    assert any(_room_of(n) == "service" for m, (_, names) in graph.items() if _is_cli(m) for n in names)


def test_the_service_client_imports_no_renderer(graph):
    """The client half (what flight software imports) names no renderer, Mitsuba or Dr.Jit module."""
    for m in ("skynav.service", "skynav.service.client", "skynav.service.protocol"):
        rel, names = graph[m]
        assert not [n for n in names if _room_of(n) in ("renderer", "calibration")
                    or n.split(".")[0] in ("mitsuba", "drjit")], rel


CLIENT_SCRIPT = textwrap.dedent("""
    import json, sys
    from skynav.service import Client, RenderResult
    from skynav.service.client import parse_multipart
    c = Client("http://127.0.0.1:9")
    loaded = sorted(m for m in sys.modules
                    if m.split(".")[0] in ("mitsuba", "drjit", "starlette", "uvicorn")
                    or m == "skynav.renderer" or m.startswith("skynav.renderer."))
    print(json.dumps({"loaded": loaded}))
""")


def test_importing_the_service_client_loads_no_renderer_mitsuba_or_drjit():
    run = subprocess.run([sys.executable, "-c", CLIENT_SCRIPT], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    assert json.loads(run.stdout.strip().splitlines()[-1])["loaded"] == []


# ----------------------------------------------------------------------------- fresh interpreter
READER_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    import skynav.datasets as D

    ds = D.open(sys.argv[1])
    rec = ds[1]
    dn, truth = rec
    obs = ds.observation(1)
    ft = ds.truth(1)
    assert obs.dn.shape == dn.shape and np.array_equal(obs.dn, dn)
    assert ft.stars.xy.shape == (len(truth["stars"]), 2)
    electrons = rec.electrons  # the EXR channel too
    loaded = sorted(m for m in sys.modules
                    if m.split(".")[0] in ("mitsuba", "drjit") or m == "skynav.renderer" or m.startswith("skynav.renderer."))
    print(json.dumps({"loaded": loaded, "shape": list(dn.shape), "stars": len(truth["stars"]),
                      "electrons": float(electrons.sum()), "epoch_tdb_s": obs.epoch_tdb_s}))
""")


def test_reading_a_dataset_loads_no_renderer_mitsuba_or_drjit(tmp_path):
    from skynav.datasets import generate

    from .datasets.conftest import small_recipe

    out = tmp_path / "ds"
    generate(small_recipe(frames=2), out, workers=1, progress=False)
    run = subprocess.run([sys.executable, "-c", READER_SCRIPT, str(out)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["loaded"] == []
    assert got["shape"] == [256, 256] and got["stars"] > 0 and got["electrons"] > 0


def test_no_datasets_module_shadows_a_public_function():
    """``skynav.datasets.preview`` etc. are functions; a submodule of the same name would replace
    the function on the package as soon as anything imported it (the lazy ``__getattr__`` is then
    never asked)."""
    import importlib
    import pkgutil

    import skynav.datasets as D

    modules = {m.name for m in pkgutil.iter_modules(D.__path__)}
    assert not modules & set(D._LAZY), modules & set(D._LAZY)
    for m in modules:  # import them all, as a doctest walk does, then the functions still resolve
        importlib.import_module(f"skynav.datasets.{m}")
    for name in D._LAZY:
        assert not isinstance(getattr(D, name), type(D)), name
