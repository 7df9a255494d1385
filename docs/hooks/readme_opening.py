"""MkDocs hook: the site's home page opens with the README's opening, said once.

The README's opening (the two commands, what the project is, its two distributions) is the
front door of both the repository and the site. docs/index.md holds the marker below in its
place; this hook puts the README's text there, from after its `# ` title to its first `## `
heading outside a code block, with the links rewritten for a page in docs/ (`docs/x.md`
becomes `x.md`, `results/...` becomes `../results/...`; the results hook publishes those).
A link to any other file of the repository cannot work on the site: `mkdocs build --strict`
fails on it, as on every link that names nothing.
"""

import re
from pathlib import Path

MARKER = "<!-- the README's opening -->"


def readme_opening(readme: str) -> str:
    """The README's text between its `# ` title and its first `## ` heading outside a fenced
    code block, with its links rewritten to name files from docs/."""
    lines = readme.splitlines()
    if not lines or not lines[0].startswith("# "):
        raise ValueError("README.md must start with its '# ' title")
    opening, in_fence = [], False
    for line in lines[1:]:
        if line.startswith("```"):
            in_fence = not in_fence
        elif line.startswith("## ") and not in_fence:
            break
        opening.append(line)
    text = "\n".join(opening).strip("\n")
    text = re.sub(r"\]\(docs/", "](", text)
    return re.sub(r"\]\((?=results/)", "](../", text)


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    root = Path(config.config_file_path).resolve().parent
    return markdown.replace(MARKER, readme_opening((root / "README.md").read_text()))
