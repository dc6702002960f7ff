"""No gear option's name is a string literal in the package outside the option's own file
and the catalog: every other module imports the name (the option's ``*_NAME`` constant or
its record's ``.name``), so renaming an option is one edit in its own file.

The scripted expert and the operator name the *phases* of their scripts (``pick``,
``insert``, ...), which are not option names; those few literals are listed below.
"""

import ast
from pathlib import Path

import dynoplan
from dynoplan.envs.gear.options.catalog import PAPER_OPTIONS
from dynoplan.envs.gear.options.give_way import GIVE_WAY_NAME
from dynoplan.envs.gear.options.insert import INSERT_NAME
from dynoplan.envs.gear.options.moves import CAUTIOUS_MOVE_NAME, FAST_MOVE_NAME
from dynoplan.envs.gear.options.pick import PICK_NAME

PACKAGE = Path(dynoplan.__file__).parent
OPTIONS = "envs/gear/options"
OWN_FILE = {"pick": f"{OPTIONS}/pick.py", "fast_move": f"{OPTIONS}/moves.py",
            "cautious_move": f"{OPTIONS}/moves.py", "insert": f"{OPTIONS}/insert.py",
            "give_way": f"{OPTIONS}/give_way.py"}
CATALOG = f"{OPTIONS}/catalog.py"
PHASES = {
    "envs/gear/expert.py": {"insert"},  # the expert's steps
    "envs/gear/options/starts.py": {"insert"},  # INSERT_STEP, the expert's step
    "envs/gear/operator.py": {"pick", "insert"},  # the operator's phases
}
"""Literals equal to an option's name that name a script's phase, by file."""


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring nodes (module, class, function and attribute docstrings:
    every string that is a statement of its own)."""
    return {id(node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)}


def name_literals(root: Path, names: set[str]) -> dict[str, set[str]]:
    """Per ``.py`` file under ``root`` (its path relative to ``root``), the names in
    ``names`` it holds as a string literal (docstrings aside)."""
    found: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        skip = _docstrings(tree)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and node.value in names and id(node) not in skip):
                found.setdefault(path.relative_to(root).as_posix(), set()).add(node.value)
    return found


def test_the_name_constants_are_the_registered_names() -> None:
    assert (PICK_NAME, FAST_MOVE_NAME, CAUTIOUS_MOVE_NAME, INSERT_NAME) == PAPER_OPTIONS
    assert set(OWN_FILE) == {*PAPER_OPTIONS, GIVE_WAY_NAME}


def test_no_option_name_is_a_literal_outside_its_own_file_and_the_catalog() -> None:
    found = name_literals(PACKAGE, set(OWN_FILE))
    stray = {file: sorted(names - PHASES.get(file, set())
                          - {n for n in names if OWN_FILE[n] == file})
             for file, names in found.items() if file != CATALOG}
    assert {file: names for file, names in stray.items() if names} == {}
    # each name is defined (as a literal) in its own file, and the scan sees it there
    assert all(name in found.get(file, set()) for name, file in OWN_FILE.items())


def test_the_scan_finds_a_literal_but_not_a_docstring(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text('"""pick, in a docstring."""\n\n\ndef f():\n'
                                   '    """insert, in a docstring."""\n'
                                   '    return f"picked {1}", ("fast_move", "lift")\n')
    (tmp_path / "b.py").write_text('X = "pick"  # insert\n"""insert: the docstring of X."""\n')
    assert name_literals(tmp_path, set(OWN_FILE)) == {"a.py": {"fast_move"}, "b.py": {"pick"}}
