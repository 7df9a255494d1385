"""MkDocs hook: publish the repository's results/ files with the site.

The learning curves and the COMMAND.txt files that go with them live in results/, outside
docs/. This hook adds them to the site's files under their repository paths, so that a page
links them as the repository does (`../results/...` from docs/, `../../results/...` from
docs/agents/): the links work in a plain checkout too, and `mkdocs build --strict` checks that
each one exists. Only small text and image files are added (no checkpoint.pt).
"""

import os
from pathlib import Path

from mkdocs.structure.files import File, InclusionLevel

SUFFIXES = {".png", ".gif", ".txt", ".csv", ".tsv", ".sh", ".py", ".toml"}
MAX_BYTES = 1_000_000


def on_files(files, config):
    docs_dir = Path(config["docs_dir"]).resolve()
    root = Path(config.config_file_path).resolve().parent
    for path in sorted((root / "results").rglob("*")):
        if path.is_file() and path.suffix in SUFFIXES and path.stat().st_size <= MAX_BYTES:
            files.append(
                File(
                    # what a link from docs/ resolves to: ../results/... (outside docs/)
                    Path(os.path.relpath(path, docs_dir)).as_posix(),
                    src_dir=str(docs_dir),
                    dest_dir=config["site_dir"],
                    use_directory_urls=config["use_directory_urls"],
                    # where the site keeps it: results/..., as in the repository
                    dest_uri=path.relative_to(root).as_posix(),
                    # set here: MkDocs's default exclusion of dot paths would match "../"
                    inclusion=InclusionLevel.INCLUDED,
                )
            )
    return files
