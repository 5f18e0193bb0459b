"""The documentation in docs/ cannot drift silently from the code.

Fails when a scene key (a field of a scene table's dataclass, or a material
model's own constant) is missing from docs/scene.md, when an option of a
command is missing from docs/cli.md, when a relative link is broken, or when
the README stops linking the docs or points at files outside the repository.
"""

from __future__ import annotations

import argparse
import dataclasses
import re

import paths
import pytest

ROOT = paths.ROOT
DOCS = ROOT / "docs"
PAGES = ("scene.md", "results.md", "api.md", "cli.md", "conventions.md", "robustness.md")


def _sections(text: str) -> dict[str, str]:
    """{heading line: body} for every '## ' section."""
    parts = re.split(r"^## ", text, flags=re.M)
    return {p.splitlines()[0]: p for p in parts[1:]}


def _table_section(sections: dict, table: str) -> str:
    for heading, body in sections.items():
        if heading.startswith((f"`[{table}]`", f"`[[{table}]]`")):
            return body
    raise AssertionError(f"docs/scene.md has no section for the [{table}] table (a heading '## `[{table}]` ...')")


def _scene_tables():
    from voxflex import scene

    return {**scene._SINGLE, **scene._ARRAYS}


def test_every_scene_table_and_key_is_documented():
    from voxflex import scene

    text = (DOCS / "scene.md").read_text(encoding="utf-8")
    sections = _sections(text)
    missing = []
    for table, spec in _scene_tables().items():
        body = _table_section(sections, table)
        for f in dataclasses.fields(spec):
            if f.name.startswith("_") or (spec is scene.MaterialSpec and f.name == "constants"):
                continue  # constants are written as the model's own keys, checked below
            if f"`{f.name}`" not in body:
                missing.append(f"[{table}] {f.name}")
    # every table of a scene, and the top-level keys
    for key in scene._TOP_KEYS:
        if key not in _scene_tables() and f"`{key}`" not in text:
            missing.append(key)
    assert not missing, f"scene keys missing from docs/scene.md: {', '.join(missing)}"


def test_every_material_constant_is_documented():
    from voxflex.deform.materials.constitutive import MATERIALS, MODEL_CONSTANTS

    body = _table_section(_sections((DOCS / "scene.md").read_text(encoding="utf-8")), "material")
    missing = [f"{model}: {c}" for model, consts in MODEL_CONSTANTS.items() for c in consts if f"`{c}`" not in body]
    missing += [f"model {m}" for m in MATERIALS if f"`{m}`" not in body]
    assert not missing, f"material keys missing from the [[material]] section of docs/scene.md: {', '.join(missing)}"


def _subcommands():
    from voxflex.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


def test_every_command_option_is_documented():
    sections = _sections((DOCS / "cli.md").read_text(encoding="utf-8"))
    commands = _subcommands()
    assert len(commands) >= 4
    missing = []
    for name, parser in commands.items():
        body = sections.get(f"`voxflex {name}`")
        if body is None:
            missing.append(f"the command '{name}'")
            continue
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            for option in action.option_strings or [action.metavar or action.dest]:
                if f"`{option}`" not in body:
                    missing.append(f"{name} {option}")
    assert not missing, f"missing from docs/cli.md: {', '.join(missing)}"


def test_docs_checks_catch_an_undocumented_key(monkeypatch):
    """The scene check is live: a new field on a scene table makes it fail."""
    from voxflex import scene

    @dataclasses.dataclass(frozen=True)
    class Extended(scene.SolverSpec):
        brand_new_key: int = 0

    monkeypatch.setitem(scene._SINGLE, "solver", Extended)
    with pytest.raises(AssertionError, match=r"\[solver\] brand_new_key"):
        test_every_scene_table_and_key_is_documented()


_LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("page", [*PAGES, "../README.md"])
def test_relative_links_resolve(page):
    path = (DOCS / page).resolve()
    text = path.read_text(encoding="utf-8")
    broken = [t for t in _LINK.findall(text) if "://" not in t and not (path.parent / t).exists()]
    assert not broken, f"{path.name}: broken links {broken}"


def test_readme_links_every_page_and_nothing_outside_the_repository():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    for page in PAGES:
        assert f"(docs/{page})" in text, f"README.md does not link docs/{page}"
    for word in ("SPEC", "NOTES", "../shared"):
        assert word not in text, f"README.md mentions {word}, which is not part of the repository"


def test_pictures_in_the_docs_are_small_pngs():
    pictures = sorted(DOCS.glob("*.png"))
    assert 2 <= len(pictures) <= 6  # a few small pictures, not a gallery: keep the repository light
    for p in pictures:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert p.stat().st_size < 200_000, f"{p.name} is {p.stat().st_size} bytes"
        assert f"({p.name})" in "".join(q.read_text(encoding="utf-8") for q in DOCS.glob("*.md")) + (
            ROOT / "README.md"
        ).read_text(encoding="utf-8").replace("docs/", ""), f"{p.name} is not shown by any page"


def test_every_voxflex_import_in_the_docs_resolves():
    """``from voxflex... import a, b`` lines in README.md and docs/ name modules and names that exist
    (the package's layout moved once; a page must not keep an old path)."""
    import importlib

    pattern = re.compile(r"^\s*(?:>>> )?from (voxflex[\w.]*) import ([\w, ]+?)\s*(?:#.*)?$", re.M)
    seen = 0
    for page in [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]:
        for module, names in pattern.findall(page.read_text(encoding="utf-8")):
            mod = importlib.import_module(module)
            for name in (n.strip().split(" as ")[0] for n in names.split(",")):
                assert hasattr(mod, name), f"{page.name}: {module} has no {name}"
                seen += 1
    assert seen >= 10  # the API page imports from the stages
