"""The checking code of the runtime's checkpoint modules, counted: the code lines (not blank, not
comments, not docstrings) of the top-level functions, classes and constants whose job is to
check or refuse what a loaded checkpoint holds (issue 103, point 5: "a format that cannot hold an
attack needs no check for it").

    python benchmarks/checking_lines.py 952b51b HEAD worktree

Each argument is a git commit (read with `git show COMMIT:PATH`) or `worktree` (the files on
disk). Every top-level name of each module must be classified below, as checking (counted) or
not (with the reason either way); a name of neither list stops the count (exit 2), so that a
new check cannot go uncounted. The lists are per format: the torch zip of 952b51b and before
(one module), and the safetensors file with a declared document from 028bfec on (three, and
flags.py, where the schema of a checkpoint's flags lives from format v4 on, beside the command
line's check that holds a run's own flags to it). Names that are identical in both formats are
classified alike in both. Imports are not counted.
"""

from __future__ import annotations

import argparse
import ast
import io
import subprocess
import sys
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNTIME = "agents/a3c_runtime"

# names alike in both formats (checkpoints.py at 952b51b; checkpoints.py or checkpoint_file.py on)
SHARED_CHECKING = {
    "check_checkpoint_path": "refuses a path that is not a file (the gate's first refusal)",
    "SCRIPT_NAME": "the rule a checkpoint's script name must follow",
    "FLAG_BOUNDS": "the bounds of a checkpoint's counts and sizes",
    "open_checkpoint": "the gate: reads and refuses",
    "env_problem": "refuses an env id the scripts do not accept",
    "CATCH_ENTRY_POINT": "the env_problem's rule for Catch",
    "load_checkpoint": "the gate for a script",
    "for_agent": "refuses another script's checkpoint, flags of the wrong type",
    "of_type": "a flag's type check",
    "checkpoint_step": "the gate's verdict (a step, or None) for the resume hint",
}
SHARED_NOT_CHECKING = {
    "CHECKPOINT_FORMAT": "the format's tag the writer writes",
    "MOVED_FLAGS": "routing: which future-work script a chapter-8 flag belongs to",
    "moved_script": "routing: looks MOVED_FLAGS up (for_agent refuses)",
    "save_checkpoint": "writing",
    "Checkpoint": "the record the gate hands on",
    "convert_command": "the text of the convert command, for messages",
    "WriteFailed": "writing",
    "PARTIAL_SUFFIX": "writing",
    "partial_path": "writing",
    "write_atomically": "writing",
    "load_network": "restoring the weights into this run's network (identical in both)",
    "restore": "restoring for --resume against this run's flags (identical in both)",
}
TORCH_ZIP = {  # 952b51b and before: agents/a3c_runtime/checkpoints.py
    "checkpoints.py": (
        {
            **SHARED_CHECKING,
            "UNSAFE_FORMATS": "the formats refused (v1: pickled worker states)",
            "verify_checkpoint": "refuses a corrupt, foreign or unsealed zip",
            "NO_SEAL": "a refusal's kind",
            "read_checkpoint": "reads safely, refuses what torch.load refuses",
            "FIELDS": "the type of each field",
            "checked": "the gate's checks of the fields",
            "malformed": "the fields' types and forms",
            "any_complex": "refuses a complex tensor anywhere in the nesting",
            "size_problem": "refuses counts and sizes out of FLAG_BOUNDS",
            "weights_problem": "refuses non-finite weights",
        },
        {
            **SHARED_NOT_CHECKING,
            "SEAL_PREFIX": "the seal's form, written and read",
            "END_OF_ARCHIVE": "the seal's form, written",
            "seal": "writing the seal",
        },
    )
}
SAFETENSORS = {  # from 028bfec on
    "checkpoint_file.py": (
        {
            "check_checkpoint_path": SHARED_CHECKING["check_checkpoint_path"],
            "MAX_HEADER": "the header's bound",
            "MAX_STEP": "a bound of the schema",
            "MAX_PENDING": "a bound of the schema",
            "MAX_WORKERS": "a bound of the schema",
            "MAX_ENVS": "a bound of the schema",
            "DTYPES": "the dtypes the schema accepts",
            "DTYPE_NAMES": "the dtypes the schema accepts, by torch dtype",
            "Strict": "the schema (pydantic)",
            "below_2_128": "the schema",
            "Uint128": "the schema",
            "Step": "the schema",
            "PCG64Words": "the schema",
            "PCG64": "the schema",
            "Worker": "the schema",
            "flag_value": "the schema",
            "Document": "the schema",
            "Entry": "the schema (a tensor's header entry)",
            "Metadata": "the schema (the header's metadata)",
            "Header": "the schema (safetensors' header)",
            "TensorName": "the schema",
            "TENSOR_TABLE": "the schema",
            "within": "the schema (a bounded count or size)",
            "Flags": "the schema (a checkpoint's flags)",
            "read_checkpoint": "refuses a corrupt or foreign file, a document the schema refuses",
            "problem_of": "the one line of a refusal",
            "older_format": "the refusal of an older format",
            "read_tensors": "refuses misplaced, non-finite or negative statistics, Catch values",
            "NOT_FINITE": "the refusals' words",
        },
        {
            "CHECKPOINT_FORMAT": SHARED_NOT_CHECKING["CHECKPOINT_FORMAT"],
            "OLDER_FORMATS": "the tags of the formats convert_checkpoint converts, for messages",
            "OlderFormat": "older_format's refusal as a type, for the sweep's advice",
            "SEAL": "the seal's place, written and read",
            "encode": "writing",
            "sealed": "writing",
            "seal_field": "the seal's form, written and read",
            "seal_digest": "the seal's form: what its SHA-256 covers, written and read",
            "pcg64": "writing",
            "storage_bytes": "writing",
            "convert_command": SHARED_NOT_CHECKING["convert_command"],
            "runtime_form": "decoding: encode's flattening undone; refuses nothing",
            "natural": "decoding",
            "generator_state": "decoding",
            "WriteFailed": "writing",
            "PARTIAL_SUFFIX": "writing",
            "partial_path": "writing",
            "write_atomically": "writing",
        },
    ),
    "checkpoints.py": (
        {
            **SHARED_CHECKING,
            "expected_table": "the tensors the flags' network has, to compare the file's with",
            "actions_of": "expected_table's action count",
            "fit_problem": "refuses a tensor table that is not the network's",
            "flag_type": "of_type's pydantic adapter",
            "flags_type": "a script's flags' types, for pydantic's strict mode",
        },
        SHARED_NOT_CHECKING,
    ),
    "flags.py": (  # the schema of a checkpoint's flags lives beside the flags (a run's own are
        # held to the same bounds on the command line): counted here as a checkpoint's schema
        {
            "MAX_STEP": "a bound of the schema",
            "MAX_WORKERS": "a bound of the schema",
            "flag_value": "the schema (a flag's value)",
            "within": "the schema (a bounded count or size)",
            "Flags": "the schema (a checkpoint's flags)",
        },
        {
            "OBSERVATION_SHAPE": "the frames' shape (the flags' checks, the networks)",
            "VALID_ENVS": "the flags' messages",
            "EVAL_EPISODES": "a flag's default",
            "UsageError": "the one-line error of every check",
            "default_num_workers": "a flag's default",
            "native_bf16": "--precision auto's rule",
            "resolve_defaults": "the command line's checks of a run's own flags",
            "check_within_checkpoint_bounds": "the command line's check of a run's own flags",
            "check_memory": "the command line's check of a run's own flags",
            "resolve_precision": "--precision",
            "autocast_contexts": "--precision",
            "refuse_tf32": "--precision",
            "probe_env": "the command line's check of --env",
            "default_text": "the flags' help",
        },
    ),
    "catch_state.py": (
        {
            "DTYPE_NAMES": "catch_layout's dtypes",
            "catch_layout": "the names, dtypes and shapes of a Catch state (its schema)",
            "catch_rules": "the bounds of Catch's values",
            "catch_problem": "refuses Catch values the games do not reach",
            "MAX_ENVS": "a bound of the schema",
            "Strict": "the schema (pydantic)",
            "Hex128": "the schema (a 128-bit word)",
            "PCG64": "the schema",
            "per_env": "the schema (a list of bounded values, one per env)",
            "CatchGames": "the schema (a worker's Catch games)",
            "RULES": "the schema's bounds (the games' rules)",
            "LAST": "the schema's bounds",
        },
        {
            "part_at": "writing: an array of the nested state",
            "POSITIONS": "the names of the positions, written and read",
            "pcg64": "writing",
            "PCG64_BYTES": "the size of a generator's state (its tensor's shape, written and read)",
            "generator_bytes": "writing: a generator's state as bytes",
            "generator_state": "decoding",
            "stored_games": "writing: a worker's Catch state in the document's and tensors' form",
            "loaded_games": "decoding: stored_games undone (the canvas and newest frames drawn)",
        },
    ),
}


def source(version: str, path: str) -> str | None:
    """The file's text at a commit (or on disk, for `worktree`); None where it does not exist."""
    if version == "worktree":
        file = ROOT / path
        return file.read_text() if file.exists() else None
    result = subprocess.run(["git", "show", f"{version}:{path}"], cwd=ROOT, capture_output=True,
                            text=True)  # fmt: skip
    return result.stdout if result.returncode == 0 else None


def code_lines(text: str) -> set[int]:
    """The lines that hold code: a token other than a comment, less docstrings (a string that is
    a statement of its own)."""
    lines = set()
    for token in tokenize.generate_tokens(io.StringIO(text).readline):
        if token.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT,
                              tokenize.DEDENT, tokenize.ENDMARKER):  # fmt: skip
            lines.update(range(token.start[0], token.end[0] + 1))
    for node in ast.walk(ast.parse(text)):
        value = node.value if isinstance(node, ast.Expr) else None
        if isinstance(value, ast.Constant) and isinstance(value.value, str):
            lines -= set(range(node.lineno, node.end_lineno + 1))
    return lines


def top_level(text: str) -> list[tuple[list[str], int]]:
    """(the names it defines, its code lines) of each top-level statement but the imports and
    the module's docstring."""
    code, out = code_lines(text), []
    for node in ast.parse(text).body:
        if isinstance(node, (ast.Import, ast.ImportFrom, ast.Expr)):
            continue
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names = [node.name]
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
        else:
            names = [f"<{type(node).__name__} at line {node.lineno}>"]
        first = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])])
        out.append((names, len({line for line in code if first <= line <= node.end_lineno})))
    return out


def count(version: str) -> int:
    """Print the checking names of each module at version, their lines and the total."""
    era = SAFETENSORS if source(version, f"{RUNTIME}/checkpoint_file.py") else TORCH_ZIP
    total, unclassified = 0, []
    for module, (checking, other) in era.items():
        text = source(version, f"{RUNTIME}/{module}")
        if text is None:
            sys.exit(f"error: {version} has no {RUNTIME}/{module}")
        counted = 0
        for names, lines in top_level(text):
            kinds = {name in checking or (False if name in other else None) for name in names}
            if None in kinds or len(kinds) != 1:
                unclassified += [f"{module}: {name}" for name in names]
            elif kinds == {True}:
                print(f"  {lines:4}  {module}: {', '.join(names)} ({checking[names[0]]})")
                counted += lines
        print(f"  {counted:4}  {module} in all")
        total += counted
    if unclassified:
        print(f"error: unclassified at {version}: {', '.join(unclassified)}", file=sys.stderr)
        sys.exit(2)
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("versions", nargs="+", help="git commits, or `worktree`")
    for version in parser.parse_args().versions:
        print(f"{version}:")
        print(f"{count(version):6}  checking lines at {version}")


if __name__ == "__main__":
    main()
