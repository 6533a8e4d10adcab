"""The README's command line is the program's: every command and option it names exists.

Reads the "Command line" section of README.md (its usage block and the prose under it)
and every ``edgecme COMMAND ...`` written anywhere in the README, and checks them against
the argparse parser (what ``--help`` prints).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from napari_edgecme.cli import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"
#: An option token: ``-o``, ``--max-blur`` (not a hyphenated word, not ``---``).
OPTION = re.compile(r"(?<![\w-])(--?[A-Za-z][\w-]*)")


@pytest.fixture(scope="module")
def commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in parser._actions for s in a.option_strings}


@pytest.fixture(scope="module")
def section() -> str:
    text = README.read_text(encoding="utf-8")
    m = re.search(r"^## Command line\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, "README.md has no '## Command line' section"
    return m.group(1)


@pytest.fixture(scope="module")
def usage(section) -> dict[str, str]:
    """The usage block: command -> the rest of its line(s) (indented lines continue it)."""
    m = re.search(r"```[a-z]*\n(.*?)```", section, re.S)
    assert m, "the Command line section has no usage block"
    lines: dict[str, str] = {}
    current = None
    for line in m.group(1).splitlines():
        head = re.match(r"edgecme ([a-z]+)\b(.*)", line)
        if head:
            current = head.group(1)
            assert current not in lines, f"{current} has two usage lines"
            lines[current] = head.group(2)
        elif line.startswith(" ") and current:
            lines[current] += " " + line.strip()
        else:
            assert not line.strip(), f"unexpected line in the usage block: {line!r}"
    return lines


def test_every_command_of_the_program_is_in_the_readme_and_no_other(commands, usage):
    assert sorted(usage) == sorted(commands)


def test_every_option_of_the_usage_block_exists_in_its_command(commands, usage):
    for name, text in usage.items():
        known = _options(commands[name])
        named = OPTION.findall(text)
        missing = [opt for opt in named if opt not in known]
        assert not missing, f"README: 'edgecme {name}' has no {missing} (see --help)"


def test_the_usage_block_names_what_each_command_requires(commands, usage):
    for name, text in usage.items():
        words = {w.rstrip(".") for w in re.findall(r"[\w.\-]+", text)}  # INPUT... -> INPUT
        for action in commands[name]._actions:
            if action.option_strings:
                if action.required:
                    assert set(action.option_strings) & words, (name, action.option_strings)
            elif not isinstance(action, argparse._SubParsersAction):
                metavar = action.metavar or action.dest.upper()
                assert metavar in words, f"README: 'edgecme {name}' lacks {metavar}"


def test_the_choices_the_usage_block_lists_are_the_programs(commands, usage):
    for name, text in usage.items():
        known = _options(commands[name])
        for opt, choices in re.findall(r"(--?[A-Za-z][\w-]*) \{([^}]*)\}", text):
            assert tuple(choices.split(",")) == tuple(known[opt].choices), (name, opt)


def test_the_defaults_the_readme_states_are_the_programs(commands, section):
    # "Defaults: `--method xu+ep`, `--model rotation`, ... `--seed 0`"
    prose = section.split("```")[-1]
    stated = re.findall(r"`(--[a-z][\w-]*) ([^`\s]+)`", prose)
    assert len(stated) >= 3, stated
    for opt, value in stated:
        having = [(n, _options(p)[opt]) for n, p in commands.items() if opt in _options(p)]
        assert having, f"README states a default for {opt}, which no command has"
        for name, action in having:
            if action.default is None or action.help == argparse.SUPPRESS:
                continue  # e.g. deconvolve's --method, the old name of --deconvolution
            assert str(action.default) == value, (name, opt, action.default, value)


def test_every_option_the_section_prose_names_exists(commands, section):
    prose = section.split("```")[-1]
    every = set().union(*(_options(p) for p in commands.values()))
    for span in re.findall(r"`([^`]+)`", prose):
        for opt in OPTION.findall(span):
            if span.startswith("python"):
                continue
            assert opt in every, f"README names {opt}, which no command has"


def test_every_edgecme_invocation_in_the_readme_is_valid(commands):
    """Anywhere in the README: ``edgecme CMD ...`` in code, the options CMD has."""
    text = README.read_text(encoding="utf-8")
    blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
    spans = re.findall(r"`([^`]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
    calls = []
    for chunk in blocks + spans:
        for line in chunk.replace("\n", " \n").split("\n"):
            for m in re.finditer(r"(?<![\w.])edgecme ([a-z]+)\b([^#]*)", line):
                calls.append((m.group(1), m.group(2)))
    assert len(calls) > 15
    for name, rest in calls:
        assert name in commands, f"README runs 'edgecme {name}', which is no command"
        known = _options(commands[name])
        rest = rest.split("edgecme ")[0]
        missing = [opt for opt in OPTION.findall(rest) if opt not in known]
        assert not missing, f"README: 'edgecme {name}{rest}' has no {missing}"
