"""Sphinx configuration of the KT-BT documentation (``make docs``).

The pages are MyST Markdown; the API reference is autodoc over the docstrings (which use reST
roles); the command-line reference is generated from the ``ktbt`` command itself
(``_ext/ktbt_cli.py``), and the spec pages include ``spec/*.md`` unchanged. Nothing is fetched
from the network and no notebook is run, so the build takes seconds.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "KT-BT"
copyright = "the KT-BT authors, MIT licence"
author = "the KT-BT authors"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "ktbt_cli",
    "ktbt_pages",
]
source_suffix = {".md": "markdown"}
master_doc = "index"
# The calibration tables are written by `ktbt sim compare` without a title: results/calibration.md
# includes them.
exclude_patterns = ["_build", "_ext", "results/calibration-*.md"]

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
# The spec's and the results' own headings are kept as they are written; a docstring's short
# :attr: name that several classes share (``refused``) resolves to none rather than failing.
suppress_warnings = ["myst.header", "ref.python"]

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": True}
# ROS 2 (the ros2 extra) and the interfaces `ktbt ros2 build` makes: not needed to document
# ktbt_proto.interop.ros2, so the site builds where they are not installed or not built yet.
autodoc_mock_imports = [
    "rclpy",
    "rcl_interfaces",
    "lifecycle_msgs",
    "ktbt_interfaces",
    "builtin_interfaces",
]
# Where a docstring's type names a class by a name autodoc cannot resolve, it stays text.
nitpicky = False

html_theme = "furo"
html_title = "KT-BT"
html_static_path: list[str] = []
