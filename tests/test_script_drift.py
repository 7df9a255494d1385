"""Copy drift: each script is the script it extends plus its idea. Every top-level definition of
the base (imports, functions, classes, constants, main) must be in the derived script unchanged,
except the derived script's allowed names: its network, NETWORK_ARGS, its flags (Args may only
add fields; the base's fields stay as they are) and, where the idea needs it, the worker or a
named function. New definitions (layers, heads, losses) are free. A fix to shared code is thus
made in a3c_ff.py and every copy, or it fails here. Chapter 8's ideas (agents/future_work/) are
held against the thesis script each extends, and an idea built on both LPQ and GLPQ is held
alike in the two."""

import ast
from pathlib import Path

import pytest
from conftest import SCRIPT_PATHS

NETWORK = {"ActorCritic", "NETWORK_ARGS", "Args"}
FUTURE = NETWORK | {"AGENT"}  # AGENT: the script's name, future_work/<file>
# (base, derived): the names the derived script may change. "Args.<field>": a field it may change.
PAIRS = {
    ("a3c_ff", "a3c_lws"): NETWORK,
    # AGENT: the value --conv-layout had in checkpoints from before the flag
    ("a3c_ff", "a3c_ss"): NETWORK | {"AGENT"},
    ("a3c_ff", "a3c_ww"): NETWORK | {"AGENT"},
    ("a3c_ff", "a3c_lstm"): NETWORK | {"worker"},  # the recurrent state through the rollout
    ("a3c_ff", "a3c_lpq"): NETWORK,
    ("a3c_ff", "a3c_glpq"): NETWORK | {"worker"},  # the tau schedule's progress, the 1/tau loss
    # GLPQ against LPQ: eq. 7.10 in place of eq. 7.9, no inverse distance (mu needs d >= 0)
    ("a3c_lpq", "a3c_glpq"): NETWORK
    | {"worker", "prototype_distances", "lpq_log_policy", "nearest_prototypes", "Args.distance"},
    ("a3c_lpq", "a3c_lpq_value_head"): FUTURE,
    ("a3c_glpq", "a3c_glpq_value_head"): FUTURE,
    ("a3c_lpq", "a3c_lpq_data_init"): FUTURE | {"Args.prototype_init"},
    ("a3c_glpq", "a3c_glpq_data_init"): FUTURE | {"Args.prototype_init"},
    ("a3c_lpq", "a3c_lpq_growth"): FUTURE | {"worker"},  # worker 0's growth step
    ("a3c_glpq", "a3c_glpq_growth"): FUTURE | {"worker", "glpq_log_policy"},  # the free slots
    ("a3c_lws", "a3c_lws_online"): FUTURE | {"LWSConv2d"},  # per-sample centroids
}
# the same idea on LPQ and on GLPQ: what it adds to its base is the same in both
IDEAS = [("a3c_lpq", "a3c_glpq", idea) for idea in ("value_head", "data_init", "growth")]
# two scripts that add the same definition to their bases, neither derived from the other: the
# definition is the same in both (WW's spatial softmax is SS's, thesis 6.2.2)
SIBLINGS = {("a3c_ss", "a3c_ww"): {"SpatialSoftmax"}}


def top_level(name: str) -> dict[str, ast.AST]:
    """The script's top-level statements by name (comments and layout do not count). An import
    `from m import (a, b)` is keyed by its module, so that a script may import more names."""
    tree = ast.parse(SCRIPT_PATHS[name].read_text())
    blocks = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            key = node.name
        elif isinstance(node, ast.Assign):
            key = ",".join(ast.unparse(t) for t in node.targets)
        elif isinstance(node, ast.ImportFrom):
            key = f"from {node.module}"
        elif isinstance(node, ast.Import):
            key = f"import {ast.unparse(node)}"
        elif isinstance(node, ast.If):
            key = f"if {ast.unparse(node.test)}"
        else:
            key = ast.dump(node)
        blocks[key] = node
    return blocks


def args_fields(node: ast.ClassDef) -> dict[str, str]:
    """Args's fields: each annotated assignment with the docstring after it."""
    fields, body = {}, node.body
    for i, statement in enumerate(body):
        if isinstance(statement, ast.AnnAssign):
            doc = body[i + 1] if i + 1 < len(body) else None
            docstring = ast.dump(doc) if isinstance(doc, ast.Expr) else ""
            fields[ast.unparse(statement.target)] = ast.dump(statement) + docstring
    return fields


def imported(node: ast.ImportFrom) -> set[str]:
    return {alias.name for alias in node.names}


def drift(base: str, derived: str, allowed: set[str]) -> list[str]:
    ours, theirs = top_level(base), top_level(derived)
    found = []
    for key, node in ours.items():
        if key not in theirs:
            if key not in allowed:
                found.append(f"{key}: missing (a copy keeps every definition of {base})")
        elif key == "Args":
            mine, other = args_fields(node), args_fields(theirs[key])
            for field, text in mine.items():
                if other.get(field) != text and f"Args.{field}" not in allowed:
                    found.append(f"Args.{field}: differs from {base}'s (a copy only adds)")
            if ast.dump(ast.Module(node.decorator_list, [])) != ast.dump(
                ast.Module(theirs[key].decorator_list, [])
            ):
                found.append("Args: decorators differ")
        elif isinstance(node, ast.ImportFrom):
            lost = imported(node) - imported(theirs[key])
            if lost or node.level != theirs[key].level:
                found.append(f"{key}: lost {sorted(lost)} (a copy may only import more)")
        elif key not in allowed and ast.dump(node) != ast.dump(theirs[key]):
            found.append(f"{key}: differs from {base}'s and is not {derived}'s to change")
    return found


@pytest.mark.parametrize(("base", "derived"), sorted(PAIRS))
def test_a_copy_changes_only_its_idea(base, derived):
    found = drift(base, derived, PAIRS[base, derived])
    assert not found, f"{derived}.py drifted from {base}.py:\n" + "\n".join(found)


@pytest.mark.parametrize(("lpq", "glpq", "idea"), IDEAS)
def test_an_idea_is_the_same_on_lpq_and_glpq(lpq, glpq, idea):
    """What agents/future_work/a3c_lpq_<idea>.py adds to a3c_lpq.py (its new definitions) is
    what a3c_glpq_<idea>.py adds to a3c_glpq.py, line for line."""
    added = {
        key: node
        for key, node in top_level(f"{lpq}_{idea}").items()
        if key not in top_level(lpq) and key not in NETWORK
    }
    assert added, "the idea adds no definition"
    other = top_level(f"{glpq}_{idea}")
    differ = [key for key, node in added.items() if ast.dump(node) != ast.dump(other.get(key))]
    assert not differ, f"{idea}: {differ} differ between the LPQ and GLPQ scripts"


def test_every_script_is_held_by_the_drift_check():
    derived = {d for _, d in PAIRS}
    assert set(SCRIPT_PATHS) - derived == {"a3c_ff"}, "a script no drift pair holds"


def change_script(name: str, old: str, new: str, tmp_path: Path, monkeypatch) -> None:
    """SCRIPT_PATHS[name] made a copy of the script with `old` replaced by `new`."""
    source = SCRIPT_PATHS[name].read_text()
    changed = source.replace(old, new)
    assert changed != source
    (tmp_path / f"{name}.py").write_text(changed)
    monkeypatch.setitem(SCRIPT_PATHS, name, tmp_path / f"{name}.py")


def test_the_drift_check_sees_a_changed_line(tmp_path, monkeypatch):
    """The check itself: a one-token change in a shared function is reported."""
    change_script("a3c_ss", "returns[t] = g", "returns[t] = g * 1.0", tmp_path, monkeypatch)
    assert any(
        line.startswith("n_step_returns: differs")
        for line in drift("a3c_ff", "a3c_ss", PAIRS["a3c_ff", "a3c_ss"])
    )


def sibling_drift(first: str, second: str, names: set[str]) -> list[str]:
    mine, theirs = top_level(first), top_level(second)
    return [
        f"{name}: differs between {first}.py and {second}.py"
        for name in sorted(names)
        if name not in mine or name not in theirs or ast.dump(mine[name]) != ast.dump(theirs[name])
    ]


@pytest.mark.parametrize(("first", "second"), sorted(SIBLINGS))
def test_a_definition_two_scripts_copy_is_the_same_in_both(first, second):
    found = sibling_drift(first, second, SIBLINGS[first, second])
    assert not found, "\n".join(found)


def test_every_definition_two_scripts_add_is_held_by_a_drift_check():
    """A definition that two scripts add to their bases (a copied layer) is held the same in
    both by PAIRS (one derived from the other), IDEAS or SIBLINGS: none is copied unwatched."""
    held = set(PAIRS) | {(f"{a}_{i}", f"{b}_{i}") for a, b, i in IDEAS}
    added: dict[str, set[str]] = {}
    for base, derived in PAIRS:
        for key in top_level(derived).keys() - top_level(base).keys() - FUTURE:
            added.setdefault(key, set()).add(derived)
    unwatched = [
        f"{key}: {first}.py and {second}.py"
        for key, scripts in sorted(added.items())
        for i, first in enumerate(sorted(scripts))
        for second in sorted(scripts)[i + 1 :]
        if (first, second) not in held
        and (second, first) not in held
        and key not in SIBLINGS.get((first, second), SIBLINGS.get((second, first), set()))
    ]
    assert not unwatched, "copied without a drift check (add it to SIBLINGS):\n" + "\n".join(
        unwatched
    )


def test_the_sibling_check_sees_a_changed_line(tmp_path, monkeypatch):
    old, new = "torch.linspace(-0.5, 0.5, size)", "torch.linspace(-1.0, 1.0, size)"
    change_script("a3c_ww", old, new, tmp_path, monkeypatch)
    assert sibling_drift("a3c_ss", "a3c_ww", {"SpatialSoftmax"}) == [
        "SpatialSoftmax: differs between a3c_ss.py and a3c_ww.py"
    ]
