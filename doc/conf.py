# Minimal Sphinx configuration: sphinx-build doc doc/_build
project = "dolfinode"
author = "dolfinode developers"
copyright = "dolfinode developers"
release = "0.1.0"

extensions = ["myst_parser"]
myst_enable_extensions = ["dollarmath"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
html_theme = "alabaster"
