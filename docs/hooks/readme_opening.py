"""MkDocs hook: the site's home page opens with the README's opening, said once.

The README's opening (the two commands, what the project is, its two distributions) is the
front door of both the repository and the site. docs/index.md holds the marker below in its
place; this hook puts the README's text there, from after its title to its first `## `
heading, with the links rewritten for a page in docs/ (`docs/x.md` becomes `x.md`,
`results/...` becomes `../results/...`). `mkdocs build --strict` then checks every one.
"""

import re
from pathlib import Path

MARKER = "<!-- the README's opening -->"


def readme_opening(readme: str) -> str:
    """The README's text between its title and its first `## ` heading, linked from docs/."""
    body = readme.split("\n", 1)[1]
    opening = body.split("\n## ", 1)[0].strip("\n")
    opening = re.sub(r"\]\(docs/", "](", opening)
    return re.sub(r"\]\((?=results/)", "](../", opening)


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    root = Path(config.config_file_path).resolve().parent
    return markdown.replace(MARKER, readme_opening((root / "README.md").read_text()))
