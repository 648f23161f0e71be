"""Sphinx configuration: MyST pages and notebooks (myst-nb), the API from docstrings.

pip install -e ".[docs]" && sphinx-build -W --keep-going docs docs/_build/html
"""

from __future__ import annotations

import minitaur_env

project = "minitaur-env"
author = "the minitaur-env developers"
copyright = "2026, the minitaur-env developers"
release = minitaur_env.__version__
version = release

extensions = [
    "myst_nb",  # MyST Markdown and notebooks (it brings myst_parser)
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.intersphinx",
    "sphinx.ext.viewcode",
]
source_suffix = {".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "**.ipynb_checkpoints"]
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3

# The notebooks are executed by the test suite (tests/test_docs.py), with a tiny budget;
# the site shows them as committed, so a docs build needs no simulator run.
nb_execution_mode = "off"

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# No network on CI machines: intersphinx inventories are not fetched, so references to
# other projects' objects stay plain text rather than breaking the -W build.
intersphinx_mapping: dict[str, tuple[str, str | None]] = {}
# Every reference to this package's objects must resolve (nitpicky); other projects'
# objects cannot, without the network, nor can names that only exist for type checkers.
nitpicky = True
nitpick_ignore_regex = [
    ("py:class", r"(pathlib|numpy|collections|gymnasium|gym|stable_baselines3|torch)\..*"),
    (
        "py:class",
        r"Path|BaseCallback|BaseAlgorithm",
    ),  # string annotations (from __future__ import annotations)
    ("py:class", r"Observation|MotorControl"),  # Literal aliases, shown by name
    ("py:class", r"minitaur_env\.(sim|robot)\..*"),  # simulator access: internal, not API
]

html_theme = "furo"
html_title = f"minitaur-env {release}"
# Inherited docstrings (gymnasium's Env.step, ...) are another project's text and markup.
autodoc_inherit_docstrings = False


def markdown_sections_to_rest(app, what, name, obj, options, lines: list[str]) -> None:
    """The env's docstring follows Gymnasium's Markdown style (``## Heading``, pipe
    tables), which ``help()`` shows as written; autodoc gets a rubric per heading and a
    literal block per table."""
    converted: list[str] = []
    index = 0
    while index < len(lines):
        line = lines[index]
        if line.startswith("## "):
            converted += [f".. rubric:: {line[3:]}", ""]
        elif line.startswith("|"):
            table = []
            while index < len(lines) and lines[index].startswith("|"):
                table.append("    " + lines[index])
                index += 1
            converted += ["::", "", *table, ""]
            continue
        else:
            converted.append(line)
        index += 1
    lines[:] = converted


def setup(app) -> None:
    app.connect("autodoc-process-docstring", markdown_sections_to_rest)
