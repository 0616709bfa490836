"""The wheel: it carries every package, the meshes with their README and licences and the viewer's static files,
and an installed copy renders a named mesh from its own assets, away from the checkout.

The wheel is built offline from a copy of the files it is made of (``pyproject.toml``, ``README.md``,
``foveawarp/``, ``assets/``), with ``pip wheel --no-deps --no-build-isolation``, so the checkout gets no
``build/`` folder. Building needs setuptools >= 77 (the SPDX licence string), declared in the dev extra.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHIPPED_MESHES = ("bunny.ply", "spot.ply", "teapot.ply", "gltf-models/Suzanne/Suzanne.gltf",
                  "gltf-models/Suzanne/Suzanne.bin", "gltf-models/Suzanne/Suzanne_BaseColor.png",
                  "gltf-models/Suzanne/Suzanne_MetallicRoughness.png", "gltf-models/Suzanne/LICENSE.md",
                  "gltf-models/ClearcoatWicker/ClearcoatWicker.glb", "gltf-models/ClearcoatWicker/LICENSE.md")
VIEWER_STATIC = ("index.html", "viewer.js", "viewer.css")


def _clean_env(pythonpath=None) -> dict:
    """The current environment without FOVEAWARP_* variables, with PYTHONPATH set to ``pythonpath`` (or unset)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOVEAWARP_") and k != "PYTHONPATH"}
    env["PYTHONUNBUFFERED"] = "1"
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return env


def _setuptools_ok() -> bool:
    try:
        import setuptools
    except ImportError:
        return False
    return tuple(int(x) for x in re.findall(r"\d+", setuptools.__version__)[:2]) >= (77, 0)


def _copy_sources(dst: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, dst / name)
    for name in ("foveawarp", "assets"):
        shutil.copytree(REPO / name, dst / name, ignore=ignore)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    if not _setuptools_ok():
        pytest.skip("building the wheel needs setuptools >= 77 (declared in the dev extra)")
    src = tmp_path_factory.mktemp("src")
    _copy_sources(src)
    dist = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation",
                        "--no-index", "-v", "-w", str(dist)], capture_output=True, text=True, env=_clean_env(),
                       timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    # the configuration builds without deprecations (licence table, undeclared data packages, ...)
    log = r.stdout + r.stderr
    assert not re.findall(r"\w*(?:Deprecation|BuildBackend)Warning", log), log[-4000:]
    (whl,) = dist.glob("foveawarp-*.whl")
    return whl


def test_wheel_holds_every_module_the_assets_and_the_viewer_page(wheel):
    z = zipfile.ZipFile(wheel)
    names = set(z.namelist())
    for f in (*SHIPPED_MESHES, "README.md", "__init__.py"):
        assert f"foveawarp/assets/{f}" in names, sorted(n for n in names if "assets" in n)
    for f in VIEWER_STATIC:
        assert f"foveawarp/viewer/static/{f}" in names, sorted(n for n in names if "viewer" in n)
    # pyproject.toml lists the packages by hand: every module under foveawarp/ must be in the wheel
    modules = {p.relative_to(REPO).as_posix() for p in (REPO / "foveawarp").rglob("*.py")
               if "__pycache__" not in p.parts}
    assert modules and modules <= names, sorted(modules - names)
    # nothing of the checkout besides the package: no tests, benchmarks, tools or a top-level assets package
    assert not [n for n in names if not n.startswith(("foveawarp/", "foveawarp-"))], sorted(names)
    # the meshes are the checkout's files, byte for byte, and their README names each with its licence
    for f in SHIPPED_MESHES:
        assert z.read(f"foveawarp/assets/{f}") == (REPO / "assets" / f).read_bytes(), f
    readme = z.read("foveawarp/assets/README.md").decode()
    for word in (*(f"`{f}`" for f in SHIPPED_MESHES), "CC0", "Stanford", "licence"):
        assert word in readme, word
    meta = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "License-Expression: MIT" in meta.splitlines(), meta[:600]


def test_installed_wheel_renders_bunny_from_its_own_assets(wheel, tmp_path):
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q", "--target",
                        str(site), str(wheel)], capture_output=True, text=True, env=_clean_env(), timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    code = textwrap.dedent("""\
        import json
        import foveawarp as fw
        from foveawarp import meshio
        s = fw.load_scene("bunny")
        print(json.dumps({"module": fw.__file__, "assets": str(meshio.assets_dir()),
                          "bunny": str(meshio.find_named_mesh("bunny")), "triangles": s.num_triangles}))
        """)
    r = subprocess.run([sys.executable, "-c", code], cwd=work, env=_clean_env(site), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    module, assets, bunny = (Path(got[k]).resolve() for k in ("module", "assets", "bunny"))
    assert module == (site / "foveawarp" / "__init__.py").resolve(), got
    assert REPO not in module.parents and REPO not in bunny.parents, got
    assert assets == (site / "foveawarp" / "assets").resolve() and bunny == assets / "bunny.ply", got
    assert got["triangles"] == 69451 + 2, got  # the bunny and the ground quad


def test_editable_install_reads_the_top_level_assets(tmp_path):
    """An editable install of this checkout resolves ``foveawarp.assets`` to the top-level ``assets/`` through the
    import system (skipped when the package is installed some other way)."""
    # the checkout's own foveawarp.egg-info may come first on sys.path: read the installer's record instead
    records = [d.read_text("direct_url.json") for d in metadata.distributions(name="foveawarp")]
    direct = next((json.loads(t) for t in records if t), {})
    url = direct.get("url", "")
    if not direct.get("dir_info", {}).get("editable") or not url.startswith("file://"):
        pytest.skip("foveawarp is not an editable install")
    if Path(url[len("file://"):]).resolve() != REPO:
        pytest.skip(f"the editable install is of another checkout ({url})")
    code = ("from importlib import resources; import foveawarp.assets as a; "
            "print(resources.files('foveawarp.assets')); print(a.__file__)")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=_clean_env(), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    files, init = (Path(line).resolve() for line in r.stdout.strip().splitlines()[-2:])
    assert files == REPO / "assets" and init == REPO / "assets" / "__init__.py", r.stdout
    assert all((files / f).is_file() for f in (*SHIPPED_MESHES, "README.md"))
