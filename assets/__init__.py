"""Package data of foveawarp: the meshes that ship with it and their licences (README.md in this folder).

The wheel installs this folder as ``foveawarp.assets``; it is a regular package so that both the wheel and an
editable install resolve it through ``importlib.resources``."""
