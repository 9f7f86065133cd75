"""The README and the user guide (docs/guide/) say only what is true of this repository.

* every ``scatterlab …`` command quoted in a code block parses with the real command-line
  parser (:func:`instrument.cli.build_parser`): the subcommand exists and takes the quoted
  options;
* every repository path quoted (in backticks or in a command) exists;
* every bench profile quoted in a TOML block validates
  (:func:`instrument.bench.profile.parse_profile`), and so does every profile in
  ``examples/``.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from instrument.bench.profile import load_profile, parse_profile
from instrument.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]
#: Top-level folders of the repository: a quoted path starting with one must exist.
REPO_DIRS = ("analysis/", "benchmarks/", "docs/", "drivers/", "examples/", "gui/",
             "hw_mocks/", "instrument/", "tests/")
#: Run files and their outputs are made by the commands themselves; not in the repository.
MADE_BY_RUNS = ("runs/",)

_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.MULTILINE | re.DOTALL)


def _blocks(text: str) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in _FENCE.finditer(text)]


def _commands(text: str) -> list[str]:
    """``scatterlab …`` lines of the shell blocks and the ``$ scatterlab …`` lines of output
    blocks (prompts and comments stripped, ``\\`` continuations joined); also ``… &&
    scatterlab …`` chains."""
    out = []
    for lang, body in _blocks(text):
        if lang not in ("bash", "sh", "console", "shell", "", "text"):
            continue
        body = body.replace("\\\n", " ")
        for line in body.splitlines():
            line = line.strip()
            if lang == "text" and not line.startswith("$ "):
                continue  # program output; "$ " marks the command that printed it
            line = line.removeprefix("$ ")
            for part in re.split(r"\s*(?:&&|;|\|)\s*", line):
                part = part.strip()
                if re.match(r"^(\.venv/bin/)?scatterlab(\s|$)", part):
                    out.append(part.split(" #", 1)[0].strip())
    return out


def _doc_ids() -> list[str]:
    return [str(p.relative_to(ROOT)) for p in DOCS]


def test_the_guide_exists_and_is_linked_from_the_readme() -> None:
    guide = ROOT / "docs" / "guide"
    assert (guide / "index.md").is_file()
    assert "docs/guide/index.md" in (ROOT / "README.md").read_text(encoding="utf-8")
    index = (guide / "index.md").read_text(encoding="utf-8")
    for page in guide.glob("*.md"):
        if page.name != "index.md":
            assert f"({page.name})" in index, f"{page.name} is not linked from index.md"


@pytest.mark.parametrize("doc", DOCS, ids=_doc_ids())
def test_quoted_commands_parse_with_the_real_parser(doc: Path) -> None:
    commands = _commands(doc.read_text(encoding="utf-8"))
    for command in commands:
        argv = shlex.split(command)[1:]
        if not argv or argv[0] in ("-h", "--help", "--version"):
            continue
        if "--help" in argv or "-h" in argv:
            argv = [a for a in argv if a not in ("--help", "-h")]
        try:
            # the parser registers the named subcommand in full (instrument.cli)
            build_parser(argv).parse_args(argv)
        except SystemExit as err:
            pytest.fail(f"{doc.name}: `{command}` does not parse (exit {err.code})")


def test_the_guide_quotes_commands_of_every_subcommand() -> None:
    """Each subcommand is shown at least once somewhere in the README or the guide."""
    from instrument.cli import SUBCOMMANDS

    shown = {shlex.split(c)[1] for d in DOCS for c in _commands(d.read_text("utf-8"))
             if len(shlex.split(c)) > 1}
    missing = {s.replace("_", "-") for s in SUBCOMMANDS} - shown
    assert not missing, f"no example of: {sorted(missing)}"


def _quoted_paths(text: str) -> set[str]:
    candidates = set(re.findall(r"`([^`\s]+)`", text))
    for command in _commands(text):
        candidates.update(shlex.split(command))
    dirs = "|".join(re.escape(d) for d in REPO_DIRS)
    for lang, body in _blocks(text):
        if lang in ("python", "toml", "json"):  # code: "instrument/..." there is an HDF5 path
            continue
        candidates.update(re.findall(rf"(?<![\w/.-])((?:{dirs})[\w./-]+)", body))
    out = set()
    for c in candidates:
        c = c.rstrip(".,:;)")
        if c.startswith(REPO_DIRS) and not c.startswith(MADE_BY_RUNS) and "*" not in c \
                and "<" not in c and not re.search(r"[A-Z]{3,}", c.split("/")[-1]):
            out.add(c)
    return out


@pytest.mark.parametrize("doc", DOCS, ids=_doc_ids())
def test_quoted_repository_paths_exist(doc: Path) -> None:
    missing = sorted(p for p in _quoted_paths(doc.read_text(encoding="utf-8"))
                     if not (ROOT / p).exists())
    assert not missing, f"{doc.name} quotes paths that do not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=_doc_ids())
def test_quoted_bench_profiles_validate(doc: Path) -> None:
    for lang, body in _blocks(doc.read_text(encoding="utf-8")):
        if lang == "toml" and re.search(r"^\[bench\]", body, re.MULTILINE):
            parse_profile(body, source=f"profile quoted in {doc.name}")


def test_example_profiles_validate() -> None:
    profiles = [p for p in sorted((ROOT / "examples").glob("*.toml"))
                if re.search(r"^\[bench\]", p.read_text(encoding="utf-8"), re.MULTILINE)]
    assert len(profiles) >= 3  # the pty rehearsal and the real benches
    for path in profiles:
        load_profile(path)


def test_the_checks_see_what_they_claim_to() -> None:
    """The extractors on a sample text: a command, a chained command, a path, a profile."""
    text = ("Run `examples/brdf_inplane.toml`:\n\n```bash\n$ scatterlab plan "
            "examples/brdf_inplane.toml --bench sim  # dry run\nsource .venv/bin/activate "
            "&& scatterlab runs --limit 3\n```\n\n```toml\n[bench]\nname = \"x\"\n"
            "[devices.camera]\ndriver = \"opencv_camera\"\nurl = \"/dev/video0\"\n```\n")
    assert _commands(text) == ["scatterlab plan examples/brdf_inplane.toml --bench sim",
                               "scatterlab runs --limit 3"]
    assert _quoted_paths(text) == {"examples/brdf_inplane.toml"}
    argv = ["plan", "x.toml", "--no-such-option"]
    with pytest.raises(SystemExit):
        build_parser(argv).parse_args(argv)
