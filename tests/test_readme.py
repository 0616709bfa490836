"""The README runs, and the package works from a clean copy and from a wheel (issue 17).

Both tests work on a temporary copy of the repository (the files git tracks plus untracked files it does not
ignore; no virtual environments, no outputs), run in subprocesses whose environment has no ``FOVEAWARP_*``
variable and whose ``PYTHONPATH`` starts with the copy, so the copy's ``foveawarp`` is imported, and with no
``shared/scenes`` folder in reach: named meshes must come from the package's assets.

README rule (also stated in README.md, "Command line"):

- every ```` ```python ```` block runs, all of them in order in one process, with ``width=<int>`` /
  ``height=<int>`` set to 64 / 36 and ``device="..."`` set to ``"cpu"``;
- every ``foveawarp ...`` command of the ```` ```bash ```` blocks runs (through ``foveawarp.cli.main``) with
  ``--device cpu``; ``demo`` / ``render`` with ``--width 48 --height 32 --frames 1`` and ``--out`` a fresh
  temporary folder; ``bench`` with ``--quick``; ``view`` with ``--width 48 --height 32 --port 0
  --serve-seconds 1``. Options are replaced where given and added where not;
- ``pip install ...`` and ``python -m pytest ...`` are not run; any other command is reported as a warning;
  ```` ```text ```` blocks (synopses) are not run. A ``foveawarp`` line with a placeholder (``[``, ``|``, ``<``)
  in a bash block fails the test: bash blocks hold runnable commands.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
import warnings
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
TOUR_SIZE = (64, 36)
CLI_SIZE = (48, 32)


def _repo_files() -> list:
    """Relative paths of the repository's files as a clean clone would have them (+ untracked, not ignored)."""
    git = shutil.which("git")
    if git and (REPO / ".git").exists():
        r = subprocess.run([git, "-C", str(REPO), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                           capture_output=True, check=False)
        if r.returncode == 0:
            return [p for p in r.stdout.decode().split("\0") if p and (REPO / p).is_file()]
    skip = {".git", ".venv", ".ci", "build", "dist", "__pycache__", ".pytest_cache", ".hypothesis", "foveawarp-out",
            "out", ".cache", ".device", ".gl", ".whl"}
    out = []
    for dirpath, dirnames, filenames in os.walk(REPO):
        dirnames[:] = [d for d in dirnames if d not in skip and not d.endswith(".egg-info")]
        for f in filenames:
            if not f.endswith(".pyc"):
                out.append(os.path.relpath(os.path.join(dirpath, f), REPO))
    return out


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    dst = tmp_path_factory.mktemp("clone") / "repo"
    for rel in _repo_files():
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, target)
    assert (dst / "foveawarp" / "assets" / "bunny.ply").is_file(), "the assets are not in the repository"
    return dst


def _clean_env(pythonpath=None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOVEAWARP_") and k != "PYTHONPATH"}
    env["PYTHONUNBUFFERED"] = "1"
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return env


def _run_py(code: str, cwd: Path, pythonpath, timeout=600) -> subprocess.CompletedProcess:
    script = cwd / "_fw_readme_script.py"
    script.write_text(code)
    try:
        return subprocess.run([sys.executable, str(script)], cwd=cwd, env=_clean_env(pythonpath), capture_output=True,
                              text=True, timeout=timeout)
    finally:
        script.unlink()


# --------------------------------------------------------------------------------------------------------------
# reading the README


def _blocks(text: str) -> list:
    """(language, body) of every fenced block."""
    return [(m.group(1).strip().lower(), m.group(2))
            for m in re.finditer(r"^```([^\n`]*)\n(.*?)^```\s*$", text, flags=re.M | re.S)]


def _set_opt(argv: list, opt: str, value) -> None:
    if opt in argv:
        i = argv.index(opt)
        argv[i + 1:i + 2] = [str(value)]
    else:
        argv += [opt, str(value)]


def readme_python(text: str) -> str:
    code = []
    for i, (lang, body) in enumerate(_blocks(text)):
        if lang in ("python", "py"):
            body = re.sub(r"\bwidth=\d+", f"width={TOUR_SIZE[0]}", body)
            body = re.sub(r"\bheight=\d+", f"height={TOUR_SIZE[1]}", body)
            body = re.sub(r"\bdevice=(\"[^\"]*\"|'[^']*')", 'device="cpu"', body)
            code.append(f"# ---- README block {i}\n{body}")
    return "\n".join(code)


def readme_commands(text: str, out_dir: Path):
    """(README line, argv for foveawarp.cli.main) for each foveawarp command; the other commands, not run."""
    runs, others = [], []
    for lang, body in _blocks(text):
        if lang not in ("bash", "sh", "shell", "console"):
            continue
        joined = re.sub(r"\\\n\s*", " ", body)
        for line in joined.splitlines():
            for cmd in re.split(r"&&|;", line):
                cmd = cmd.strip()
                if not cmd or cmd.startswith("#"):
                    continue
                words = shlex.split(cmd, comments=True)
                if not words:
                    continue
                if words[0] != "foveawarp":
                    if not (words[0] == "pip" or words[:3] == ["python", "-m", "pytest"]):
                        others.append(cmd)
                    continue
                if any(c in cmd.split("#")[0] for c in "[|<"):
                    raise AssertionError(f"README bash line is a synopsis, not a command (use a ```text block): {cmd}")
                argv = words[1:]
                sub = argv[0] if argv else ""
                _set_opt(argv, "--device", "cpu")
                if sub in ("demo", "render"):
                    _set_opt(argv, "--width", CLI_SIZE[0])
                    _set_opt(argv, "--height", CLI_SIZE[1])
                    _set_opt(argv, "--frames", 1)
                    _set_opt(argv, "--out", out_dir / f"cmd{len(runs)}")
                if sub == "bench" and "--quick" not in argv:
                    argv.append("--quick")
                if sub == "view":   # the live viewer: a free port, a tiny size, stop after a second
                    _set_opt(argv, "--width", CLI_SIZE[0])
                    _set_opt(argv, "--height", CLI_SIZE[1])
                    _set_opt(argv, "--port", 0)
                    _set_opt(argv, "--serve-seconds", 1)
                runs.append((cmd, argv))
    return runs, others


def test_readme_rules_rewrite_as_documented(tmp_path):
    text = textwrap.dedent("""\
        ```bash
        pip install -e .[dev] && foveawarp demo
        foveawarp render --scene bunny --width 1280 --height 720 \\
                         --device cuda:0 --out out/b   # a comment
        python -m pytest
        ```
        ```text
        foveawarp render [--scene NAME]
        ```
        ```python
        loop = fw.FrameLoop(s, width=1920, height=1080, device="cuda:0")
        ```
        """)
    runs, others = readme_commands(text, tmp_path)
    assert [r[0] for r in runs][0] == "foveawarp demo"
    assert runs[0][1] == ["demo", "--device", "cpu", "--width", "48", "--height", "32", "--frames", "1", "--out",
                          str(tmp_path / "cmd0")]
    assert runs[1][1] == ["render", "--scene", "bunny", "--width", "48", "--height", "32", "--device", "cpu",
                          "--out", str(tmp_path / "cmd1"), "--frames", "1"]
    assert others == [] and len(runs) == 2
    assert 'width=64, height=36, device="cpu"' in readme_python(text)
    with pytest.raises(AssertionError, match="synopsis"):
        readme_commands("```bash\nfoveawarp render [--scene NAME]\n```\n", tmp_path)


# --------------------------------------------------------------------------------------------------------------
# running it


def test_readme_runs_from_a_clean_copy(clone, tmp_path):
    text = (clone / "README.md").read_text()
    tour = readme_python(text)
    assert "fw.load_scene" in tour and "FrameLoop" in tour, "the README's Python tour is missing"
    runs, others = readme_commands(text, tmp_path)
    for cmd in others:
        warnings.warn(f"README command not run by tests/test_readme.py: {cmd}")
    scenes = {a[a.index("--scene") + 1] for _, a in runs if "--scene" in a}
    assert {"bunny", "spot"} <= scenes, f"the README should show the shipped named meshes, shows {scenes}"
    assert {a[0] for _, a in runs} >= {"demo", "render", "warmup", "bench"}

    # the Python blocks, in one process, from the copy
    probe = ("import foveawarp as _fw, foveawarp.meshio as _mio\n"
             "print('FOVEAWARP_FILE', _fw.__file__)\n"
             "print('NEFERTITI', _mio.find_named_mesh('nefertiti'))\n")
    r = _run_py(probe + tour, clone, clone)
    assert r.returncode == 0, f"README Python tour failed:\n{r.stdout[-3000:]}\n{r.stderr[-5000:]}"
    assert f"FOVEAWARP_FILE {clone / 'foveawarp' / '__init__.py'}" in r.stdout, r.stdout[-2000:]
    assert "NEFERTITI None" in r.stdout, "a shared scene folder is in reach: the test would not show a clean clone"

    # the foveawarp commands, through the console script's main(), one process
    (tmp_path / "cmds.json").write_text(json.dumps([[c, a] for c, a in runs]))
    driver = textwrap.dedent(f"""\
        import json, sys, traceback
        import foveawarp
        from foveawarp.cli import main
        print("FOVEAWARP_FILE", foveawarp.__file__)
        for line, argv in json.load(open({str(tmp_path / "cmds.json")!r})):
            print("RUN", line, flush=True)
            try:
                rc = main(argv)
            except SystemExit as e:
                rc = e.code if e.code is not None else 0
            except Exception:
                traceback.print_exc()
                rc = "exception"
            if rc != 0:
                sys.exit(f"README command failed (exit {{rc}}): {{line}}  [run as foveawarp {{' '.join(argv)}}]")
        print("ALL_OK")
        """)
    r = _run_py(driver, clone, clone)
    assert r.returncode == 0 and "ALL_OK" in r.stdout, f"{r.stdout[-4000:]}\n{r.stderr[-5000:]}"
    assert f"FOVEAWARP_FILE {clone / 'foveawarp' / '__init__.py'}" in r.stdout
    for cmd, argv in runs:
        if argv[0] in ("demo", "render"):
            out = Path(argv[argv.index("--out") + 1])
            assert (out / "frame_0000.png").is_file() and (out / "stats.json").is_file(), cmd
            stats = json.loads((out / "stats.json").read_text())
            assert stats["width"] == CLI_SIZE[0] and stats["device"] == "cpu"


def _wheel_tools_ok() -> bool:
    try:
        import setuptools
    except ImportError:
        return False
    major_minor = tuple(int(x) for x in re.findall(r"\d+", setuptools.__version__)[:2])
    if major_minor >= (70, 1):
        return True
    try:
        import wheel  # noqa: F401
    except ImportError:
        return False
    return True


def test_wheel_carries_the_assets_and_renders_bunny(clone, tmp_path):
    if not _wheel_tools_ok():
        pytest.skip("needs setuptools >= 70.1 (declared in the dev extra) or the wheel package to build a wheel")
    src = tmp_path / "src"
    shutil.copytree(clone, src)
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "-q",
                        "-w", str(dist)], capture_output=True, text=True, env=_clean_env(), timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    (whl,) = dist.glob("foveawarp-*.whl")
    names = set(zipfile.ZipFile(whl).namelist())
    for f in ("bunny.ply", "spot.ply", "teapot.ply", "README.md"):
        assert f"foveawarp/assets/{f}" in names, sorted(n for n in names if "assets" in n)
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q", "--target",
                        str(site), str(whl)], capture_output=True, text=True, env=_clean_env(), timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    code = textwrap.dedent(f"""\
        import foveawarp as fw
        from foveawarp.cli import main
        from foveawarp.meshio import find_named_mesh
        print("FILE", fw.__file__)
        print("BUNNY", find_named_mesh("bunny"))
        rc = main(["render", "--scene", "bunny", "--device", "cpu", "--width", "32", "--height", "24",
                   "--frames", "1", "--no-panel", "--out", {str(work / "out")!r}])
        print("RC", rc)
        """)
    r = _run_py(code, work, site)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert f"FILE {site / 'foveawarp' / '__init__.py'}" in r.stdout, r.stdout
    assert f"BUNNY {site / 'foveawarp' / 'assets' / 'bunny.ply'}" in r.stdout, r.stdout
    assert "RC 0" in r.stdout and (work / "out" / "frame_0000.png").is_file()
    stats = json.loads((work / "out" / "stats.json").read_text())
    assert stats["scene"] == "bunny" and stats["triangles"] == 69451 + 2
