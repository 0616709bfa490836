"""README.md and docs/: the README's commands run, every relative link resolves, the pages stay within their
length and describe the package as it is (no process words).

The README is run from a temporary copy of the repository (the files git tracks plus untracked files it does not
ignore), in subprocesses whose environment has no ``FOVEAWARP_*`` variable and whose ``PYTHONPATH`` starts with
the copy, so the copy's ``foveawarp`` is imported and no ``shared/scenes`` folder is in reach: named meshes come
from the package's assets. The rules:

- every ```` ```python ```` block runs, all of them in order in one process, with ``width=<int>`` /
  ``height=<int>`` set to 64 / 36 and ``device="..."`` set to ``"cpu"``;
- every ``foveawarp ...`` command of the ```` ```bash ```` blocks runs (through ``foveawarp.cli.main``) with
  ``--device cpu``; ``demo`` / ``render`` with ``--width 48 --height 32 --frames 1`` and ``--out`` a fresh
  temporary folder; ``bench`` with ``--quick``; ``view`` with ``--width 48 --height 32 --port 0
  --serve-seconds 1``; a command without a subcommand (``foveawarp --help``) as written. Options are replaced
  where given and added where not;
- ``pip install ...`` and ``python -m pytest ...`` lines are not run (``.ci/run`` runs both); any other command in
  a bash block fails the test, and so does a ``foveawarp`` line with a placeholder (``[``, ``|``, ``<``): bash
  blocks hold runnable commands, ```` ```text ```` blocks synopses and commands for other machines.
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
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
DOCS = REPO / "docs"
TOUR_SIZE = (64, 36)
CLI_SIZE = (48, 32)
README_MAX_LINES = 400
DOCS_MAX_LINES = 1500
IMAGE_MAX_BYTES = 1_100_000


def _pages() -> list:
    """README.md and every markdown page under docs/."""
    return [README] + sorted(DOCS.rglob("*.md"))


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


def _not_run(words: list) -> bool:
    """The install and test lines, which ``.ci/run`` runs itself."""
    return words[0] == "pip" or words[:3] == ["python", "-m", "pytest"]


def readme_commands(text: str, out_dir: Path) -> list:
    """(README line, argv for foveawarp.cli.main) for each foveawarp command of the bash blocks."""
    runs = []
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
                if not words or _not_run(words):
                    continue
                if words[0] != "foveawarp":
                    raise AssertionError(f"README bash line is not a foveawarp command this test can run (move it to "
                                         f"a ```text block): {cmd}")
                if any(c in cmd.split("#")[0] for c in "[|<"):
                    raise AssertionError(f"README bash line is a synopsis, not a command (use a ```text block): {cmd}")
                argv = words[1:]
                sub = argv[0] if argv else ""
                if sub.startswith("-") or not sub:  # foveawarp --help: as written
                    runs.append((cmd, argv))
                    continue
                _set_opt(argv, "--device", "cpu")
                if sub in ("demo", "render"):
                    _set_opt(argv, "--width", CLI_SIZE[0])
                    _set_opt(argv, "--height", CLI_SIZE[1])
                    _set_opt(argv, "--frames", 1)
                    _set_opt(argv, "--out", out_dir / f"cmd{len(runs)}")
                if sub == "bench" and "--quick" not in argv:
                    argv.append("--quick")
                if sub == "view":  # the live viewer: a free port, a tiny size, stop after a second
                    _set_opt(argv, "--width", CLI_SIZE[0])
                    _set_opt(argv, "--height", CLI_SIZE[1])
                    _set_opt(argv, "--port", 0)
                    _set_opt(argv, "--serve-seconds", 1)
                runs.append((cmd, argv))
    return runs


def test_readme_rules_rewrite_as_documented(tmp_path):
    text = textwrap.dedent("""\
        ```bash
        pip install -e .[dev] && foveawarp demo
        foveawarp render --scene bunny --width 1280 --height 720 \\
                         --device cuda:0 --out out/b   # a comment
        foveawarp --help
        python -m pytest
        ```
        ```text
        foveawarp render [--scene NAME]
        ssh -L 8765:127.0.0.1:8765 host
        ```
        ```python
        loop = fw.FrameLoop(s, width=1920, height=1080, device="cuda:0")
        ```
        """)
    runs = readme_commands(text, tmp_path)
    assert [r[0] for r in runs][0] == "foveawarp demo"
    assert runs[0][1] == ["demo", "--device", "cpu", "--width", "48", "--height", "32", "--frames", "1", "--out",
                          str(tmp_path / "cmd0")]
    assert runs[1][1] == ["render", "--scene", "bunny", "--width", "48", "--height", "32", "--device", "cpu",
                          "--out", str(tmp_path / "cmd1"), "--frames", "1"]
    assert runs[2][1] == ["--help"] and len(runs) == 3
    assert 'width=64, height=36, device="cpu"' in readme_python(text)
    with pytest.raises(AssertionError, match="synopsis"):
        readme_commands("```bash\nfoveawarp render [--scene NAME]\n```\n", tmp_path)
    with pytest.raises(AssertionError, match="not a foveawarp command"):
        readme_commands("```bash\nssh -L 1:2:3 host\n```\n", tmp_path)


# --------------------------------------------------------------------------------------------------------------
# the pages themselves


def test_lengths():
    n = len(README.read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines, at most {README_MAX_LINES}"
    per = {p.relative_to(REPO).as_posix(): len(p.read_text().splitlines()) for p in DOCS.rglob("*") if p.is_file()
           and p.suffix.lower() in (".md", ".txt", ".rst")}
    assert sum(per.values()) <= DOCS_MAX_LINES, f"docs/ has {sum(per.values())} lines, at most {DOCS_MAX_LINES}: {per}"


_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _relative_links(text: str) -> list:
    out = []
    for target in _LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, flags=re.I) or target.startswith("#"):
            continue  # http:, https:, mailto: and in-page anchors
        out.append(target.split("#", 1)[0])
    return out


def test_relative_links_and_images_exist():
    missing = []
    for page in _pages():
        for target in _relative_links(page.read_text()):
            path = (page.parent / target).resolve()
            if not path.exists():
                missing.append(f"{page.relative_to(REPO)}: {target}")
            elif path.suffix.lower() in (".png", ".jpg", ".jpeg", ".gif"):
                size = path.stat().st_size
                assert size <= IMAGE_MAX_BYTES, f"{page.relative_to(REPO)}: {target} is {size} bytes"
    assert not missing, "links to missing files:\n" + "\n".join(missing)
    assert "docs/images/overview.png" in _relative_links(README.read_text()), "the README's output picture"


def test_link_check_sees_broken_links(tmp_path):
    text = "![a](docs/images/overview.png) [b](docs/nothing-here.md#x) [c](https://example.org/x.md) [d](#top)"
    assert _relative_links(text) == ["docs/images/overview.png", "docs/nothing-here.md"]


# process words: what the tree is, not how it came to be
_FORBIDDEN = [
    (re.compile(r"\bsessions?\b", re.I), "'session'"),
    (re.compile(r"\bissues?\s*#?\d", re.I), "an issue number"),
    (re.compile(r"\bhelpers?\b", re.I), "'helper'"),
    # a commit hash: 7-40 hex characters with at least one digit and one letter, as a word of its own
    (re.compile(r"(?<![\w])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}(?![\w])"), "a commit hash"),
    (re.compile(r"\b(?:commit|commits) [0-9a-f]{6,}", re.I), "a commit hash"),
    (re.compile(r"(?<![\w`])I (?=[a-z])|(?<![\w`])I'(?:m|ve|d|ll)\b"), "first person 'I'"),
    (re.compile(r"\b(?:we|our|ours|ourselves)\b", re.I), "first person 'we'"),
    (re.compile(r"(?<![\w.])/(?:work|tmp|home|root|Users)/"), "a machine path"),
]


def _process_words(text: str) -> list:
    found = []
    for i, line in enumerate(text.splitlines(), 1):
        for rx, what in _FORBIDDEN:
            m = rx.search(line)
            if m:
                found.append(f"line {i}: {what}: {m.group(0)!r} in {line.strip()[:100]!r}")
    return found


def test_no_process_words():
    bad = []
    for page in _pages():
        bad += [f"{page.relative_to(REPO)} {b}" for b in _process_words(page.read_text())]
    assert not bad, "\n".join(bad)


# the code's comments and docstrings: the same rule, narrower patterns (``session`` is a viewer and a pytest word,
# ``helper`` a function's, hex digits are data)
_FORBIDDEN_CODE = [
    (re.compile(r"\bsessions? ?\d|\(sessions? ?\d", re.I), "a work period"),
    (re.compile(r"\bissues? ?#?\d", re.I), "an issue number"),
    (re.compile(r"#.*\b(?:we|our)\b|\b(?:we|our) (?:measured|found|chose|use|keep|do|did|have)\b", re.I),
     "first person 'we'"),
    (re.compile(r"#\s*I (?=[a-z]{2})|[.;:]\s+I (?=[a-z]{2})|\bI (?:measured|found|chose|think|did)\b"),
     "first person 'I'"),
    (re.compile(r"(?<![\w.])/(?:work|home|Users)/"), "a machine path"),
]
_CODE_GLOBS = ("foveawarp/**/*.py", "foveawarp/**/*.js", "foveawarp/**/*.html", "benchmarks/*.py", "tools/*",
               "tests/**/*.py", ".ci/*", "pyproject.toml")


def _code_files() -> list:
    files = set()
    for g in _CODE_GLOBS:
        files.update(p for p in REPO.glob(g) if p.is_file() and "__pycache__" not in p.parts)
    return sorted(files - {Path(__file__).resolve()})


def test_no_process_words_in_code():
    bad = []
    for f in _code_files():
        for i, line in enumerate(f.read_text(errors="replace").splitlines(), 1):
            for rx, what in _FORBIDDEN_CODE:
                m = rx.search(line)
                if m:
                    bad.append(f"{f.relative_to(REPO)}:{i}: {what}: {m.group(0)!r}")
    assert len(_code_files()) > 50
    assert not bad, "\n".join(bad)


# the forbidden words below carry a "~" that _unmask removes, so this file itself passes the checks it tests
def _unmask(line: str) -> str:
    return line.replace("~", "")


@pytest.mark.parametrize("line", ["# measured in sess~ion 28", "(sess~ion 18)", "see iss~ue 14", "w~e chose 4",
                                  "# I~ measured it", "/wo~rk/main/x"])
def test_code_process_word_check_catches(line):
    line = _unmask(line)
    assert any(rx.search(line) for rx, _ in _FORBIDDEN_CODE), line


@pytest.mark.parametrize("line", [
    "Measured in sess~ion 33 on the H100.", "Iss~ue 14's targets", "fixed in `a565fab`", "at 0c09545 the frame",
    "I~ measured it", "w~e chose 4", "Ou~r default", "a help~er review", "see /wo~rk/main/README.md",
    "(commit 7614501)", "results/cpu-16core-2e786dc-cpu.md",
])
def test_process_word_check_catches(line):
    line = _unmask(line)
    assert _process_words(line), line


@pytest.mark.parametrize("line", [
    "27 us per launch", "the viewer listens on 127.0.0.1", "0x2545F491", "float32 and 1e-30", "I_c = Phi",
    "`tools/canonical.sh`", "(H, W, 3) float32", "deadbeef", "SSIM (sigma 1.5)", "benchmarks/results/frame-h200.md",
])
def test_process_word_check_passes(line):
    assert not _process_words(line), _process_words(line)


# --------------------------------------------------------------------------------------------------------------
# running it


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
        out += [os.path.relpath(os.path.join(dirpath, f), REPO) for f in filenames if not f.endswith(".pyc")]
    return out


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    dst = tmp_path_factory.mktemp("clone") / "repo"
    for rel in _repo_files():
        if rel.startswith(("benchmarks/results/", "docs/images/")):
            continue  # large outputs the README's code does not read
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, target)
    assert (dst / "assets" / "bunny.ply").is_file(), "the assets are not in the repository"
    return dst


def _clean_env(pythonpath) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOVEAWARP_") and k != "PYTHONPATH"}
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONPATH"] = str(pythonpath)
    return env


def _run_py(code: str, cwd: Path, timeout=600) -> subprocess.CompletedProcess:
    script = cwd / "_fw_readme_script.py"
    script.write_text(code)
    try:
        return subprocess.run([sys.executable, str(script)], cwd=cwd, env=_clean_env(cwd), capture_output=True,
                              text=True, timeout=timeout)
    finally:
        script.unlink()


def test_readme_python_runs_from_a_clean_copy(clone):
    tour = readme_python((clone / "README.md").read_text())
    assert "fw.load_scene" in tour and "FrameLoop" in tour and "frame.stats" in tour, "the quick start is missing"
    probe = ("import foveawarp as _fw, foveawarp.meshio as _mio\n"
             "print('FOVEAWARP_FILE', _fw.__file__)\n"
             "print('NEFERTITI', _mio.find_named_mesh('nefertiti'))\n")
    r = _run_py(probe + tour, clone)
    assert r.returncode == 0, f"README Python block failed:\n{r.stdout[-3000:]}\n{r.stderr[-5000:]}"
    assert f"FOVEAWARP_FILE {clone / 'foveawarp' / '__init__.py'}" in r.stdout, r.stdout[-2000:]
    assert "NEFERTITI None" in r.stdout, "a shared scene folder is in reach: the test would not show a clean clone"
    assert "PSNR against full resolution" in r.stdout, r.stdout[-2000:]


def test_readme_commands_run_from_a_clean_copy(clone, tmp_path):
    runs = readme_commands((clone / "README.md").read_text(), tmp_path)
    subs = {a[0] for _, a in runs if a}
    assert {"demo", "render", "view", "--help"} <= subs, f"the README should show these commands, shows {subs}"
    scenes = {a[a.index("--scene") + 1] for _, a in runs if "--scene" in a}
    assert {"bunny", "spot"} <= scenes, f"the README should show the shipped named meshes, shows {scenes}"
    (tmp_path / "cmds.json").write_text(json.dumps([[c, a] for c, a in runs]))
    driver = textwrap.dedent(f"""\
        import contextlib, io, json, sys, traceback
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
    r = _run_py(driver, clone)
    assert r.returncode == 0 and "ALL_OK" in r.stdout, f"{r.stdout[-4000:]}\n{r.stderr[-5000:]}"
    assert f"FOVEAWARP_FILE {clone / 'foveawarp' / '__init__.py'}" in r.stdout
    assert "usage: foveawarp" in r.stdout, "foveawarp --help printed no usage"
    for cmd, argv in runs:
        if argv and argv[0] in ("demo", "render"):
            out = Path(argv[argv.index("--out") + 1])
            assert (out / "frame_0000.png").is_file() and (out / "stats.json").is_file(), cmd
            stats = json.loads((out / "stats.json").read_text())
            assert stats["width"] == CLI_SIZE[0] and stats["device"] == "cpu"


# --------------------------------------------------------------------------------------------------------------
# the paths they name, and the results at a glance

# benchmarks/NAME.py and tools/NAME as the pages write them (placeholders such as NAME or <benchmark> left out)
_TREE_PATH = re.compile(r"(?<![\w/.-])((?:benchmarks/[a-z0-9_]+\.py)|(?:tools/[a-z0-9_]+\.(?:py|sh)))(?![\w/-])")


def _tree_paths(text: str) -> list:
    return _TREE_PATH.findall(text)


def test_named_benchmarks_and_tools_exist():
    """Every benchmarks/*.py and tools/* path that README.md or a docs/ page names is in the tree, and the README
    names every benchmark entry point."""
    missing = [f"{page.relative_to(REPO)}: {path}" for page in _pages() for path in _tree_paths(page.read_text())
               if not (REPO / path).is_file()]
    assert not missing, "pages name files that are not in the tree:\n" + "\n".join(missing)
    named = set(_tree_paths(README.read_text()))
    entry_points = {f"benchmarks/{f.name}" for f in (REPO / "benchmarks").glob("*.py") if not f.stem.startswith("_")}
    assert entry_points <= named, f"the README does not name {sorted(entry_points - named)}"


def test_tree_path_check_sees_missing_paths():
    text = ("run `benchmarks/frame.py` and tools/canonical.sh, not benchmarks/quality.py or tools/status.py; "
            "benchmarks/NAME.py and benchmarks/results/frame-h200.md are not entry points")
    assert _tree_paths(text) == ["benchmarks/frame.py", "tools/canonical.sh", "benchmarks/quality.py",
                                 "tools/status.py"]


def _frame_bench():
    if str(REPO) not in sys.path:
        sys.path.append(str(REPO))
    from benchmarks import frame

    return frame


def results_problem(text: str, canonical: Path, ci: bool):
    """What is wrong with a README's results at a glance: None when they are what ``benchmarks/frame.py
    --summarize`` prints from ``canonical`` (relative to the repository), "skip: ..." when ``canonical`` is missing
    and that is allowed, else the failure's message. Under CI a table without its JSON is a failure."""
    frame = _frame_bench()
    shown = frame.readme_results(text)
    if shown is None:
        return f"README.md lacks the results markers {frame.README_BEGIN!r} ... {frame.README_END!r}"
    if not canonical.is_file():
        if ci and any(line.startswith("|") for line in shown.splitlines()):
            return f"README.md shows a results table but {canonical.name} is missing"
        return f"skip: {canonical.name} is not in the tree (tools/canonical.sh part1 writes it)"
    if shown != frame.summarize(canonical).strip():
        return (f"README.md's results differ from {canonical.name}: run python benchmarks/frame.py --summarize "
                f"benchmarks/results/frame-h200.json --readme README.md")
    return None


def test_readme_results_table_is_the_canonical_json():
    """The README's results at a glance are what ``benchmarks/frame.py --summarize`` prints from
    benchmarks/results/frame-h200.json, plot link included. Without that file: skipped, except under CI=true when
    the README holds a table (figures that nothing in the tree backs)."""
    problem = results_problem(README.read_text(), REPO / "benchmarks" / "results" / "frame-h200.json",
                              os.environ.get("CI", "").lower() == "true")
    if problem and problem.startswith("skip: "):
        pytest.skip(problem[6:])
    assert problem is None, problem


def test_results_check_sees_a_stale_or_unbacked_table(tmp_path):
    frame = _frame_bench()
    rec = {"scene": "bunny", "width": 64, "height": 36, "config": "default", "ao_samples": 0,
           "quality_target": "render_reference", "ref_ms": 2.0, "fov_ms": 1.0, "speedup": 2.0, "auto_ms": 1.0,
           "auto_path": "foveated", "psnr_mean": 40.0, "psnr_min": 38.0, "ssim_mean": 0.99}
    j = tmp_path / "frame-h200.json"
    j.write_text(json.dumps({"benchmark": "frame", "device": "NVIDIA H200", "warp": "1.19.0", "frames": 30,
                             "timing_frames": 30, "records": [rec]}))
    good = f"{frame.README_BEGIN}\n{frame.summarize(j)}{frame.README_END}\n"
    assert results_problem(good, j, ci=True) is None
    assert "differ" in results_problem(good.replace("2.00x", "2.50x"), j, ci=True)
    assert "lacks the results markers" in results_problem("no markers", j, ci=False)
    gone = tmp_path / "missing.json"
    assert "is missing" in results_problem(good, gone, ci=True)
    assert results_problem(good, gone, ci=False).startswith("skip: ")
    empty = f"{frame.README_BEGIN}\n{frame.README_END}\n"
    assert results_problem(empty, gone, ci=True).startswith("skip: ")
