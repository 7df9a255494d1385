"""The runs of chapter 8's ideas on Catch, as the analyses of them (future_work_summary,
future_work_growth, future_work_trained_scale) take them: a folder of configurations, each a
sweep's folder (CONFIG/results.csv; CONFIG/runs/ where the sweep ran on this machine, as run
folders are not committed), results/future_work_catch unless the command line names another.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from a3c_tools import ROOT, tool_parser

FOLDER = ROOT / "results" / "future_work_catch"


def folder_argument(
    tool: str,
    description: str,
    argv: list[str] | None,
    with_runs: Callable[[Path], Iterable[str]] = lambda folder: (),
) -> Path:
    """An analysis's command line: its one argument, the configurations' folder. It must be a
    folder, holding run folders for the configurations with_runs(folder) names; where not,
    argparse's one-line error, exit 2."""
    parser = tool_parser(tool, description)
    parser.add_argument(
        "folder",
        nargs="?",
        type=Path,
        default=FOLDER,
        help="the configurations' folder (default results/future_work_catch)",
    )
    folder = parser.parse_args(argv).folder
    if not folder.is_dir():
        parser.error(f"{folder} is not a folder")
    runs = [folder / config / "runs" for config in with_runs(folder)]
    missing = [str(path) for path in runs if not path.is_dir()]
    if missing:
        parser.error(f"no run folders ({', '.join(missing)}): run the configurations first")
    return folder
