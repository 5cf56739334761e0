"""The user documentation stays true to the product: every setting of the settings class is in
docs/settings.md, every `intspace` command and flag in docs/cli.md, every twin scenario in
docs/scenarios.md; every relative link of README.md and docs/*.md reaches a file (and a heading,
when it names one); the commands they show parse, the files and modules they name exist, and
the README's tour computes what it says it computes."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import json
import os
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from core.sim.scenarios import SCENARIOS
from server.cli import build_parser
from server.settings import Settings

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = [REPO / "README.md", *sorted(DOCS.glob("*.md"))]
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.M | re.S)
_HEADING = re.compile(r"^(#{1,6}) +(.+?) *$", re.M)


def _slug(heading: str) -> str:
    """Return GitHub's anchor of a heading: lower case, punctuation dropped, spaces to dashes."""
    text = re.sub(r"[`*_]", "", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _prose(text: str) -> str:
    """Return a page without its fenced code blocks (a '#' there is a comment, not a heading)."""
    return _FENCE.sub("", text)


def _sections(text: str) -> dict[str, str]:
    """Return each heading's own text (up to the next heading of any level), by heading."""
    prose = _prose(text)
    marks = list(_HEADING.finditer(prose))
    return {
        m[2]: prose[m.end() : marks[k + 1].start() if k + 1 < len(marks) else len(prose)]
        for k, m in enumerate(marks)
    }


def _first_column(section: str) -> list[str]:
    """Return the first cells of a section's table rows (header and rule left out)."""
    rows = [line for line in section.splitlines() if line.startswith("| ")]
    return [row.split(" | ")[0].lstrip("| ") for row in rows[2:]]


# -- settings ------------------------------------------------------------------------------------


def test_every_setting_is_documented_with_its_default_and_no_other():
    page = (DOCS / "settings.md").read_text(encoding="utf-8")
    documented: dict[str, str] = {}
    for section in _sections(page).values():
        for row in [line for line in section.splitlines() if line.startswith("| `INTSPACE_")]:
            names, default, meaning = (cell.strip() for cell in row.strip("|").split(" | ")[:3])
            assert meaning, f"{names} has no meaning in docs/settings.md"
            variables = re.findall(r"`INTSPACE_(\w+)`", names)
            # A row of several variables gives their defaults in the same order.
            defaults = default.split("`, `") if len(variables) > 1 else [default]
            assert len(defaults) == len(variables), row
            for name, value in zip(variables, defaults, strict=True):
                documented[name.lower()] = value
    fields = Settings.model_fields
    missing = sorted(set(fields) - set(documented))
    assert not missing, f"settings not in docs/settings.md: {missing}"
    stale = sorted(set(documented) - set(fields))
    assert not stale, f"docs/settings.md documents settings the class lacks: {stale}"
    # Each documented default is the class's; a generated or derived one (None) is in words.
    for name, field in fields.items():
        default = field.get_default(call_default_factory=True)
        shown = documented[name]
        if default is None:
            continue
        if isinstance(default, bool):
            assert shown.startswith(f"`{str(default).lower()}`"), (name, shown)
        elif isinstance(default, int | float):
            assert float(default) in [float(v) for v in re.findall(r"[\d.]+", shown)], (
                name,
                default,
                shown,
            )
        elif isinstance(default, Path):
            assert f"./{default}" in shown, (name, default, shown)
        else:
            assert str(default) in shown, (name, default, shown)


# -- command line --------------------------------------------------------------------------------


def _commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    found = {path: parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_commands(sub, (*path, name)))
    return found


def test_every_command_and_flag_is_in_the_cli_page():
    page = (DOCS / "cli.md").read_text(encoding="utf-8")
    sections = _sections(page)
    commands = _commands(build_parser())
    for path, parser in commands.items():
        if not path:
            continue
        name = "intspace " + " ".join(path)
        assert name in page, f"docs/cli.md never names {name!r}"
        # A command's flags are in the section of its own heading, else of its parent's.
        owner = next(
            (
                " ".join(path[:k])
                for k in range(len(path), 0, -1)
                if f"intspace {' '.join(path[:k])}" in sections
            ),
            None,
        )
        assert owner is not None, f"docs/cli.md has no section for {name!r}"
        text = sections[f"intspace {owner}"]
        flags = [
            option
            for action in parser._actions
            for option in action.option_strings
            if option.startswith("--") and option != "--help"
        ]
        missing = [flag for flag in flags if f"`{flag}" not in text]
        assert not missing, f"{name}: flags missing from its section of docs/cli.md: {missing}"
        # ... and the section's table names no flag the command lacks.
        for cell in _first_column(text):
            for flag in re.findall(r"`(--[\w-]+)", cell):
                assert flag in flags, f"docs/cli.md's {name} documents {flag}, which it lacks"


# -- scenarios -----------------------------------------------------------------------------------


def test_every_scenario_has_its_section_and_no_other():
    page = (DOCS / "scenarios.md").read_text(encoding="utf-8")
    headings = [m[2] for m in _HEADING.finditer(_prose(page)) if m[1] == "##"]
    assert sorted(headings) == sorted(SCENARIOS), (headings, list(SCENARIOS))
    for name, section in _sections(page).items():
        if name in SCENARIOS:
            assert "**Inputs**" in section and "**Figures**" in section, name


# -- links ---------------------------------------------------------------------------------------


def test_every_relative_link_reaches_a_file_and_its_heading():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for target in _LINK.findall(_prose(text)):
            if re.match(r"^[a-z]+:", target):
                continue  # http(s), mailto: not ours to check offline
            path, _, anchor = target.partition("#")
            where = (page.parent / path).resolve() if path else page
            assert where.exists(), f"{page.name} links {target}, which does not exist"
            if anchor:
                anchors = {_slug(m[2]) for m in _HEADING.finditer(_prose(where.read_text()))}
                assert anchor in anchors, f"{page.name} links {target}: no such heading"


def test_the_readme_links_every_page_of_the_docs():
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    linked = {t.partition("#")[0] for t in _LINK.findall(readme)}
    pages = {f"docs/{p.name}" for p in DOCS.glob("*.md")}
    assert not pages - linked, f"pages the README does not link: {sorted(pages - linked)}"


# -- commands and code shown ---------------------------------------------------------------------


def _shown_commands() -> list[tuple[str, str]]:
    """Return (page, command line) of every `intspace ...` line the pages show: in code blocks
    and inline code, environment assignments in front dropped, comments and continuations
    joined."""
    found = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        blocks = [body for lang, body in _FENCE.findall(text) if lang in ("", "bash")]
        lines = [
            line.split(" #")[0]
            for body in blocks
            for line in body.replace("\\\n", " ").splitlines()
        ]
        inline = re.findall(r"`([^`\n]*(?:\n[^`\n]*)?)`", _prose(text))
        for line in lines + [" ".join(s.split()) for s in inline]:
            words = line.split()
            while words and "=" in words[0] and not words[0].startswith("-"):
                words.pop(0)
            # "intspace node: ..." is what the node prints, not a command.
            if len(words) > 1 and words[0] == "intspace" and not words[1].endswith(":"):
                found.append((page.name, " ".join(words)))
    return found


def test_the_intspace_commands_shown_parse():
    parser = build_parser()
    commands = _commands(parser)
    shown = _shown_commands()
    assert len(shown) > 20, shown  # the pages show the commands (the parsing above works)
    for page, line in shown:
        words = line.split()[1:]
        path: tuple[str, ...] = ()
        while words and (*path, words[0]) in commands:
            path = (*path, words.pop(0))
        assert path, f"{page}: {line!r} names no intspace command"
        synopsis = any(c in line for c in "[]|()<>") or "..." in line
        argv = [*path, "--help"] if synopsis else shlex.split(line)[1:]
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                args = parser.parse_args(argv)
            except SystemExit as exc:
                # --help exits 0; a bad flag or value 2 with the reason.
                assert exc.code == 0, f"{page}: {line!r} does not parse: {out.getvalue()}"
                continue
        assert getattr(args, "func", None) is not None, f"{page}: {line!r} runs nothing"


def test_the_make_targets_files_and_modules_shown_exist():
    makefile = (REPO / "Makefile").read_text(encoding="utf-8")
    targets = set(re.findall(r"^([\w-]+):", makefile, re.M))
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"`make ([\w-]+)`|^make ([\w-]+)", text, re.M):
            name = target[0] or target[1]
            assert name in targets, f"{page.name}: make {name} is not a Makefile target"
        for module in re.findall(r"python -m (bench\.\w+)", text):
            assert (REPO / (module.replace(".", "/") + ".py")).is_file(), (page.name, module)
        for bench in re.findall(r"^\| `(bench_\w+)`", text, re.M):
            assert (REPO / "bench" / f"{bench}.py").is_file(), (page.name, bench)
        for path in re.findall(
            r"`((?:docker|bench|core|server|web|migrations|tests)/[\w./-]+)`", text
        ):
            assert (REPO / path.rstrip("/")).exists(), f"{page.name}: {path} does not exist"


def test_the_code_map_names_every_package():
    # docs/code-map.md is the newcomer's map: a package it leaves out is one nobody finds. That
    # what it names exists is the test above's.
    text = (DOCS / "code-map.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`((?:core|server)(?:/[\w]+)*)`", text))
    packages = {
        str(init.parent.relative_to(REPO))
        for top in ("core", "server")
        for init in (REPO / top).rglob("__init__.py")
    }
    assert sorted(packages - named) == []


def test_the_python_shown_compiles_and_its_imports_exist():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for lang, body in _FENCE.findall(text):
            if lang != "python":
                continue
            compile(body, f"{page.name} code block", "exec")
            for module, names in re.findall(r"^from (core[\w.]*) import (.+)$", body, re.M):
                imported = importlib.import_module(module)
                for name in (n.strip() for n in names.split(",")):
                    assert hasattr(imported, name), f"{page.name}: {module} has no {name}"


def test_the_readme_tour_calibrates_zhangs_data_as_it_says(tmp_path, shared_data_dir, monkeypatch):
    """The tour's script writes the correspondences file; the calibration it describes (skew,
    k1k2) gives fx = 832.50 px and an RMS of 0.336 px, the README's two figures."""
    from core.calibration import calibrate_camera

    readme = (REPO / "README.md").read_text(encoding="utf-8")
    (script,) = [
        body for lang, body in _FENCE.findall(readme.replace("\n   ", "\n")) if lang == "python"
    ]
    data = shared_data_dir / "zhang1998"
    if not data.is_dir():
        # Like the calibration tests on this data: required in CI, skipped on a checkout
        # without ../shared.
        message = f"Zhang's data not found at {data}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    # The script is run from the repository's root, where ../shared/data is.
    monkeypatch.chdir(tmp_path)
    exec(compile(script.replace("../shared/data/zhang1998", str(data)), "README", "exec"), {})
    written = json.loads((tmp_path / "zhang.json").read_text())
    assert written["image_size"] == [640, 480] and len(written["image_points"]) == 5
    assert all(len(view) == 256 for view in written["image_points"])
    fit = calibrate_camera(
        [np.array(o) for o in written["object_points"]],
        [np.array(i) for i in written["image_points"]],
        (640, 480),
        skew=True,
        distortion="k1k2",
    )
    # The README gives fx to 0.01 px and the RMS to 0.001 px: half a unit of the last digit.
    assert abs(fit.K[0, 0] - 832.50) <= 0.005, fit.K
    assert abs(fit.rms - 0.336) <= 0.0005, fit.rms
