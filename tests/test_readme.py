"""Every code block of README.md and docs/*.md runs or validates as written.

Each block is checked by its kind; a block of a kind this module does not know fails, so that a
new example cannot go unchecked:

- ``yaml`` blocks: a manifest (it has ``objects``) goes through ``icefarm validate`` (exit 0, no
  warning); a render config loads through `icefarm.scene.config.load_render_config`. A block
  whose first line is a comment naming a file (``# garden.yaml``) is written under that name, so
  the commands that follow can name it.
- ``sh`` blocks and indented blocks: one command a line (``&&`` chains split, ``#`` comments
  dropped), in a workspace folder where ``out/`` (the docs' output folder) is a temporary one,
  an absolute ``-o`` folder is moved under it, and ``scenes/`` and ``render_configs/`` are the
  repo's. Cheap ``icefarm`` commands run (``validate``, ``params``, ``--help``, ``sweep`` with
  ``--dry-run`` added); the others (jobs, renders, sheets, benchmarks) are parsed by click with
  the options of the same command, the folders they read created empty (what an earlier step
  would have written). Jobs stopped early (``icefarm run ... --until``) and the README's first
  job, with the exports of its folder, run for real in the slow tests below. Other commands
  are known one by one (``.ci/setup.sh``, pytest, the Dask cluster's ``dask scheduler`` and
  ``dask worker``, ``usdview``).
- ``python`` blocks: compiled here; in the slow test below, each page's blocks run in order in
  one namespace (as a reader pastes them into one session), in the same workspace folder.

Links between the pages must lead to a page and a heading that exist.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = (README, *sorted((ROOT / "docs").glob("*.md")))
ICEFARM = ("icefarm", ".venv/bin/icefarm")
SHELL = ("sh", "bash", "console", "shell", "")  # "": an indented block
RENDER_KEYS = {"renderer", "variant", "resolution", "spp", "max_depth", "denoise", "views", "fov", "ice",
               "environment"}
NAMED = re.compile(r"#\s*([\w.-]+\.ya?ml)\b")
FIRST_JOB = "icefarm run generator:sign -o out/sign"  # the README's first job: run for real (slow)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # 1-based line of the block's first line of code
    info: str  # the fence's language; "" for an indented block
    text: str

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def code_blocks(page: Path) -> list[Block]:
    """The fenced (``` or ~~~) and indented code blocks of ``page``, CommonMark's rules
    simplified: an indented block starts after a blank line, 4 spaces past the content of the
    list item it sits in (if any)."""
    lines = page.read_text().splitlines()
    blocks: list[Block] = []
    i, list_indent, blank = 0, None, True
    while i < len(lines):
        line = lines[i]
        fence = re.match(r"^ {0,3}(`{3,}|~{3,})\s*([\w+-]*)", line)
        if fence:
            end = next((j for j in range(i + 1, len(lines)) if lines[j].strip().startswith(fence.group(1))), None)
            assert end is not None, f"{page.name}:{i + 1}: unclosed code fence"
            blocks.append(Block(page, i + 2, fence.group(2).lower(), "\n".join(lines[i + 1:end])))
            i, blank = end + 1, False
            continue
        indent = len(line) - len(line.lstrip(" "))
        if line.strip() and blank and indent >= (list_indent or 0) + 4:
            j = i
            while j < len(lines) and (not lines[j].strip() or lines[j].startswith(" " * ((list_indent or 0) + 4))):
                j += 1
            blocks.append(Block(page, i + 1, "", "\n".join(ln.strip() for ln in lines[i:j]).strip()))
            i, blank = j, False
            continue
        item = re.match(r"^( {0,3})([-*+]|\d+[.)]) +", line)
        if item:
            list_indent = len(item.group(0))
        elif line.strip() and indent < (list_indent or 0):
            list_indent = None
        blank = not line.strip()
        i += 1
    return blocks


BLOCKS = [block for page in PAGES for block in code_blocks(page)]


def commands(block: Block) -> list[list[str]]:
    """The shell commands of a block, as argument lists."""
    found = []
    for line in block.text.splitlines():
        words = shlex.split(line, comments=True)
        while words:
            cut = words.index("&&") if "&&" in words else len(words)
            found.append(words[:cut])
            words = words[cut + 1:]
    return found


def yaml_name(block: Block) -> str:
    named = NAMED.match(block.text.lstrip())
    return named.group(1) if named else f"block_{block.page.stem}_{block.line}.yaml"


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """The folder the docs' commands run in: the repo's scenes and render configs, every named
    YAML block of the docs, and ``out/`` empty."""
    root = tmp_path_factory.mktemp("docs")
    for name in ("scenes", "render_configs"):
        (root / name).symlink_to(ROOT / name)
    for block in BLOCKS:
        if block.info == "yaml":
            (root / yaml_name(block)).write_text(block.text + "\n")
    (root / "out").mkdir()
    return root


def invoke(args: list[str]):
    from icefarm.cli import main

    return CliRunner().invoke(main, args, catch_exceptions=False)


def moved_out(args: list[str], root: Path) -> list[str]:
    """``args`` with an absolute output folder moved under ``root``."""
    args = list(args)
    for i, word in enumerate(args[:-1]):
        if word in ("-o", "--out") and args[i + 1].startswith("/"):
            args[i + 1] = str(root / args[i + 1].lstrip("/"))
    return args


def parse(args: list[str], root: Path) -> None:
    """Parse ``icefarm ARGS`` with click as the command would, without running it; the folders
    under ``out/`` that it reads are created empty (an earlier step would have written them)."""
    import click

    from icefarm.cli import main

    for i, word in enumerate(args):
        if word.startswith("out/") and (i == 0 or args[i - 1] not in ("-o", "--out")) and "." not in Path(word).name:
            (root / word).mkdir(parents=True, exist_ok=True)
    ctx = click.Context(main, info_name="icefarm")
    command: click.Command = main
    words = list(args)
    while isinstance(command, click.Group):  # down the subcommands: `bench table2 ...`
        assert words, f"icefarm {' '.join(args)}: no subcommand"
        name, words = words[0], words[1:]
        sub = command.get_command(ctx, name)
        assert sub is not None, f"icefarm {' '.join(args)}: no command {name}"
        command = sub
        ctx = click.Context(sub, info_name=name, parent=ctx)
    with command.make_context(ctx.info_name, words, parent=ctx.parent) as parsed:
        assert not parsed.args, f"icefarm {' '.join(args)}: left over {parsed.args}"


def check_icefarm(args: list[str], root: Path) -> str:
    """Check one ``icefarm`` command; returns how (for the test's own check)."""
    args = moved_out(args, root)
    sub = args[0] if args else ""
    if "--help" in args or "-h" in args or sub == "params":
        result = invoke(args)
        assert result.exit_code == 0, result.output
        return "ran"
    if sub == "validate":
        result = invoke(args)
        assert result.exit_code == 0, result.output
        assert "warning" not in result.stderr, result.stderr
        return "ran"
    if sub == "sweep":
        result = invoke([*args, "--dry-run"] if "--dry-run" not in args else args)
        assert result.exit_code == 0, result.output
        assert "warning" not in result.stderr, result.stderr
        return "dry run"
    if sub in ("run", "render", "export", "sheet", "report", "bench"):
        parse(args, root)
        return "parsed"
    raise AssertionError(f"icefarm {sub}: no way to check this command; teach tests/test_readme.py")


def check_command(words: list[str], root: Path) -> str:
    """Check one shell command of the docs."""
    program, args = words[0], words[1:]
    if program in ICEFARM:
        return check_icefarm(args, root)
    if program == "bash" and args == [".ci/setup.sh"]:
        assert (ROOT / ".ci/setup.sh").is_file()
        return "exists"
    if program == ".venv/bin/python" and args[:2] == ["-m", "pytest"]:
        rest = args[2:]
        assert rest[:1] == ["-q"], rest
        if rest[1:]:
            assert rest[1] == "-m" and len(rest) == 3, rest
            text = (ROOT / "pyproject.toml").read_text()
            for marker in set(re.findall(r"\w+", rest[2])) - {"not", "and", "or"}:
                assert f'"{marker}:' in text, f"pytest marker {marker} is not registered in pyproject.toml"
        return "parsed"
    if program == "dask" and args[:1] in (["scheduler"], ["worker"]):
        from distributed.cli import dask_scheduler, dask_worker

        command = {"scheduler": dask_scheduler.main, "worker": dask_worker.main}[args[0]]
        with command.make_context(f"dask {args[0]}", args[1:]) as ctx:
            assert not ctx.args, ctx.args
        return "parsed"
    if program == "usdview":
        from icefarm.jobdir import SCENE_USDA

        assert len(args) == 1 and Path(args[0]).name == SCENE_USDA, args
        return "names a job's file"
    raise AssertionError(f"{program}: no way to check this command; teach tests/test_readme.py")


def check_yaml(block: Block, root: Path) -> None:
    data = yaml.safe_load(block.text)
    assert isinstance(data, dict), f"{block.name}: a YAML block must be a manifest or a render config"
    path = root / yaml_name(block)
    if "objects" in data:
        result = invoke(["validate", str(path)])
        assert result.exit_code == 0, result.output
        assert "warning" not in result.stderr, result.stderr
    elif set(data) <= RENDER_KEYS:
        from icefarm.scene.config import load_render_config

        load_render_config(path)
    else:
        raise AssertionError(f"{block.name}: neither a manifest nor a render config: {sorted(data)}")


@pytest.mark.parametrize("block", BLOCKS, ids=[b.name for b in BLOCKS])
def test_every_block_runs_validates_or_parses(block, workspace, monkeypatch):
    monkeypatch.chdir(workspace)
    if block.info in ("yaml", "yml"):
        check_yaml(block, workspace)
    elif block.info == "python":
        compile(block.text, block.name, "exec")
    elif block.info in SHELL:
        found = commands(block)
        assert found, f"{block.name}: an empty block"
        for words in found:
            check_command(words, workspace)
    else:
        raise AssertionError(f"{block.name}: a ```{block.info} block: no way to check it; teach tests/test_readme.py")


def test_an_unknown_block_or_command_fails(tmp_path):
    page = tmp_path / "x.md"
    page.write_text("text\n\n```python\nprint(1)\n```\n\nmore\n\n    make all\n\n- item\n\n  not code\n")
    found = code_blocks(page)
    assert [(b.info, b.text) for b in found] == [("python", "print(1)"), ("", "make all")]
    with pytest.raises(AssertionError, match="no way to check"):
        check_command(["make", "all"], tmp_path)
    with pytest.raises(AssertionError, match="no way to check"):
        check_icefarm(["frobnicate"], tmp_path)


def test_the_readme_is_the_users_path():
    text = README.read_text()
    assert len(text.splitlines()) < 300
    for command in ("bash .ci/setup.sh && .venv/bin/icefarm sweep scenes/demo.yaml -o out --overwrite",
                    "bash .ci/setup.sh && .venv/bin/python -m pytest -q"):
        assert f"\n{command}\n" in text, command  # CI runs the second as written
    assert any(FIRST_JOB in b.text for b in BLOCKS if b.page == README)


def test_the_readme_names_the_sweep_folders_files():
    from icefarm import jobdir

    layout = README.read_text().split("### The sweep folder", 1)[1]
    for name in (jobdir.MANIFEST, jobdir.JOBS_CSV, jobdir.JOBS_DIR, jobdir.CACHE_DIR, jobdir.SHEETS_DIR,
                 jobdir.REPORT_MD, jobdir.REPORT_CSV):
        assert f"`{name}" in layout, name


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_links_lead_to_pages_and_headings(page):
    for target, fragment in re.findall(r"\]\(([^)#\s]*\.md)?(?:#([\w-]+))?\)", page.read_text()):
        linked = (page.parent / target).resolve() if target else page
        assert linked.is_file(), f"{page.name}: link to {target}"
        if fragment:
            headings = {anchor(h) for h in re.findall(r"^#+ (.+)$", linked.read_text(), flags=re.M)}
            assert fragment in headings, f"{page.name}: no heading #{fragment} in {linked.name}"


@pytest.mark.slow  # runs jobs (a few seconds each): the docs' stopped-early jobs
def test_jobs_stopped_early_run_as_written(workspace, monkeypatch):
    monkeypatch.chdir(workspace)
    stopped = [words[1:] for b in BLOCKS if b.info in SHELL for words in commands(b)
               if words[0] in ICEFARM and words[1:2] == ["run"] and "--until" in words]
    assert stopped
    for args in stopped:
        result = invoke(moved_out(args, workspace))
        assert result.exit_code == 0, result.output
        assert "warning" not in result.stderr, result.stderr


@pytest.mark.slow  # grows ice and renders thumbnails through the Python API (docs/api.md: about 20 s)
def test_python_blocks_run_as_written(workspace, monkeypatch):
    monkeypatch.chdir(workspace)
    pages = {block.page for block in BLOCKS if block.info == "python"}
    assert pages
    for page in sorted(pages):
        namespace: dict = {"__name__": "__main__"}
        for block in (b for b in BLOCKS if b.page == page and b.info == "python"):
            exec(compile(block.text, block.name, "exec"), namespace)


@pytest.mark.slow  # runs and renders the README's first job (about 20 s), then exports it
def test_the_first_job_its_exports_and_the_layout(workspace, monkeypatch):
    from icefarm import jobdir

    monkeypatch.chdir(workspace)
    result = invoke(shlex.split(FIRST_JOB)[1:])
    assert result.exit_code == 0, result.output
    assert "warning" not in result.stderr, result.stderr
    job = workspace / "out/sign"
    written = sorted(p.name for p in job.iterdir())
    assert {jobdir.DONE, jobdir.RENDER_PNG, jobdir.SCENE_USDA} <= set(written), written
    exports = [words[1:] for b in BLOCKS if b.info in SHELL for words in commands(b)
               if words[0] in ICEFARM and words[1:3] == ["export", "out/sign"]]
    assert exports
    for args in exports:
        result = invoke(moved_out(args, workspace))
        assert result.exit_code == 0, result.output
    assert (job / jobdir.EXPORT_DIR / "scene.glb").is_file()
    # The README's table of a job folder names every file the job wrote.
    layout = README.read_text().split("### The job folder", 1)[1].split("###", 1)[0]
    named = set(re.findall(r"`([\w.*/-]+)`", layout))
    missing = [name for name in written if name not in named and not name.startswith("sky_")]
    assert not missing, f"README's job folder leaves out {missing}"
    assert any(name.startswith("sky_") for name in written) and "sky_az120_el45.exr" in named
