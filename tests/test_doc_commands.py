"""Every ``aev-ocp …`` command line in README.md and docs/**/*.md is accepted by the command's parser.

Concrete lines are parsed in full (parse only, nothing runs); synopsis lines (placeholders in capitals,
``[optional]``, ``{a,b}``, ``a|b``) must name a known sub-command and only options it has.
"""

from __future__ import annotations

import argparse

import re
import shlex
from pathlib import Path

import pytest

from aev_ocp.cli import build_parser, command_parser, parse_command_line

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
# every sub-command the top-level parser knows (a new one is checked without editing this file)
SUBCOMMANDS = tuple(next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices)


def command_lines(text: str) -> list[str]:
    """The ``aev-ocp …`` command lines of a Markdown text: in code blocks (a line starting with whitespace
    and '[' continues the previous one; '&&' separates commands; '#' starts a comment) and in inline code."""
    out: list[str] = []
    prose: list[str] = []
    fence = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fence = not fence
            prose.append("")
            continue
        if fence:
            body = line.split(" #", 1)[0].rstrip()
            if re.match(r"\s+\[", body) and out and out[-1].startswith("aev-ocp "):
                out[-1] += " " + body.strip()
                continue
            for part in body.split("&&"):
                part = part.strip().removeprefix("$ ").strip()
                if part.startswith("aev-ocp ") or part == "aev-ocp":
                    out.append(part)
        else:
            prose.append(line)
    # inline code may run over a line break
    out += [" ".join(m.split()) for m in re.findall(r"`(aev-ocp(?:\s[^`]*)?)`", "\n".join(prose))]
    return out


def is_synopsis(cmd: str) -> bool:
    """A line with placeholders ([optional], {a,b}, a|b, ..., capitalised names) rather than values."""
    return bool(re.search(r"[\[\]{}|…]|\.\.\.|\b[A-Z][A-Z_=0-9]+\b", cmd))


def problems(cmd: str) -> list[str]:
    """Why ``cmd`` would not be accepted (empty list: fine)."""
    words = cmd.split()[1:]
    if not words or words[0].startswith("--"):
        return [] if not words or words[0] in ("--version", "--help") else [f"{cmd}: no sub-command"]
    name = re.split(r"[|{\[]", words[0])[0]
    if name not in SUBCOMMANDS:
        return [f"{cmd}: unknown sub-command {name!r}"]
    if len(words) == 1:  # the command named in prose ("`aev-ocp mpc` solves ..."), not a command line
        return []
    if is_synopsis(cmd):
        known = set(command_parser(name)._option_string_actions)
        return [
            f"{cmd}: {name} has no option {flag}"
            for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", cmd)
            if flag not in known
        ]
    try:
        parse_command_line(shlex.split(cmd)[1:])
    except SystemExit as exc:
        return [f"{cmd}: refused by the parser (exit {exc.code})"] if exc.code else []
    return []


def _all() -> list[tuple[str, str]]:
    return [(p.relative_to(ROOT).as_posix(), c) for p in DOCS for c in command_lines(p.read_text(encoding="utf-8"))]


def test_docs_hold_command_lines() -> None:
    found = _all()
    assert len(found) > 20 and {c.split()[1] for _, c in found if len(c.split()) > 1} >= {"simulate", "mpc", "study"}


@pytest.mark.parametrize("where, cmd", _all())
def test_every_documented_command_line_parses(where: str, cmd: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert problems(cmd) == [], where


@pytest.mark.parametrize(
    "cmd, word",
    [
        ("aev-ocp simulate table1 --time-limt 30", "refused"),  # a typo in a concrete line
        ("aev-ocp simulate SCENARIO [--out DIR] [--no-such-flag S]", "--no-such-flag"),  # an option a synopsis invents
        ("aev-ocp simulat table1", "unknown sub-command"),
        ("aev-ocp mpc mpc_paper_single --t-end -3", "refused"),
    ],
)
def test_the_check_catches_a_bad_line(cmd: str, word: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert any(word in p for p in problems(cmd))


def test_the_extractor_reads_code_blocks_continuations_and_inline_code() -> None:
    text = (
        "run `aev-ocp mpc x.toml --t-end 60` now\n```\naev-ocp ocp prop31 [--out DIR]\n"
        "            [--N N]   # comment\npip install . && aev-ocp reproduce\n```\n"
    )
    text += "and `aev-ocp study s.toml\n--set a.b=1` too\n"
    assert command_lines(text) == [
        "aev-ocp ocp prop31 [--out DIR] [--N N]",
        "aev-ocp reproduce",
        "aev-ocp mpc x.toml --t-end 60",
        "aev-ocp study s.toml --set a.b=1",
    ]


def _test_command(text: str) -> str:
    """The pytest command of the README's test line (``… && pytest …``) or of .ci/run (a line starting with pytest)."""
    lines = [ln.split("&&")[-1].strip() for ln in text.splitlines() if re.search(r"(^|&& )pytest ", ln.strip())]
    assert len(lines) == 1, lines
    return lines[0]


def test_readme_docs_and_ci_run_the_same_test_command() -> None:
    """CI runs the README's test command (the docs' start page shows it too): one change to it changes all three,
    e.g. the xdist distribution that keeps a file's shared results on one worker."""
    readme = _test_command(
        next(
            ln for ln in (ROOT / "README.md").read_text(encoding="utf-8").splitlines() if "pip install '.[test]'" in ln
        )
    )
    docs = _test_command(
        next(
            ln
            for ln in (ROOT / "docs" / "index.md").read_text(encoding="utf-8").splitlines()
            if "pip install '.[test]'" in ln
        )
    )
    ci = _test_command((ROOT / ".ci" / "run").read_text(encoding="utf-8"))
    assert readme == docs == ci, (readme, docs, ci)
    assert readme.startswith("pytest -q -n auto")
