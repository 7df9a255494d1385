"""Copy drift: each variant is a3c_ff.py plus its idea. Every top-level definition of a3c_ff.py
(imports, functions, classes, constants, main) must be in each variant unchanged, except the
variant's allowed names: its network, NETWORK_ARGS, its flags (Args may only add fields; a3c_ff's
fields stay as they are) and, for the variants that change the loop, the worker. New
definitions (layers, heads, losses) are free. A fix to shared code is thus made in a3c_ff.py and
every variant, or it fails here."""

import ast

import pytest
from conftest import AGENTS

NETWORK = {"ActorCritic", "NETWORK_ARGS", "Args"}
ALLOWED = {
    "a3c_lws": NETWORK,
    # AGENT: the value --conv-layout had in checkpoints from before the flag
    "a3c_ss": NETWORK | {"AGENT"},
    "a3c_ww": NETWORK | {"AGENT"},
    "a3c_lstm": NETWORK | {"worker"},  # the recurrent state through the rollout
    # AGENT: initialize, for --prototype-init data
    "a3c_lpq": NETWORK | {"AGENT"},
    "a3c_glpq": NETWORK | {"AGENT", "worker"},  # the tau schedule's progress and the 1/tau loss
}


def top_level(name: str) -> dict[str, str]:
    """The script's top-level statements by name, each as its AST dump (comments and layout
    do not count)."""
    tree = ast.parse((AGENTS / f"{name}.py").read_text())
    blocks = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            key = node.name
        elif isinstance(node, ast.Assign):
            key = ",".join(ast.unparse(t) for t in node.targets)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
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


@pytest.mark.parametrize("variant", sorted(ALLOWED))
def test_variant_changes_only_its_network_flags_and_loop(variant):
    ff, other = top_level("a3c_ff"), top_level(variant)
    drift = []
    for key, node in ff.items():
        if key not in other:
            drift.append(f"{key}: missing (the variants keep every a3c_ff definition)")
        elif key == "Args":
            ours, theirs = args_fields(node), args_fields(other[key])
            for field, text in ours.items():
                if theirs.get(field) != text:
                    drift.append(f"Args.{field}: differs from a3c_ff's (a variant only adds)")
            if ast.dump(ast.Module(node.decorator_list, [])) != ast.dump(
                ast.Module(other[key].decorator_list, [])
            ):
                drift.append("Args: decorators differ")
        elif key not in ALLOWED[variant] and ast.dump(node) != ast.dump(other[key]):
            drift.append(f"{key}: differs from a3c_ff's and is not {variant}'s to change")
    assert not drift, f"{variant}.py drifted from a3c_ff.py:\n" + "\n".join(drift)


def test_the_drift_check_sees_a_changed_line(tmp_path, monkeypatch):
    """The check itself: a one-token change in a shared function is reported."""
    import conftest

    source = (AGENTS / "a3c_ss.py").read_text()
    changed = source.replace("returns[t] = g", "returns[t] = g * 1.0")
    assert changed != source
    (tmp_path / "a3c_ss.py").write_text(changed)
    (tmp_path / "a3c_ff.py").write_text((AGENTS / "a3c_ff.py").read_text())
    monkeypatch.setattr(conftest, "AGENTS", tmp_path)
    monkeypatch.setitem(globals(), "AGENTS", tmp_path)
    with pytest.raises(AssertionError, match="n_step_returns: differs"):
        test_variant_changes_only_its_network_flags_and_loop("a3c_ss")
