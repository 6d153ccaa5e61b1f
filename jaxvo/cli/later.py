"""A host module's constant that a command's parser reads only when argparse uses it."""

from __future__ import annotations

import importlib


class Later:
    """A host module's constant read when argparse first uses it (the help printed, a value
    checked against its choices), not when the parser is built: those modules import NumPy,
    which a one-line answer need not wait for. A help's ``%(name)s`` is filled from the
    option's attribute ``name``; as ``choices``, a ``metavar`` keeps it off the usage line.

    Args:
      module: the module that holds it (``"jaxvo.host.frontend.camera"``).
      name: its name there (``"PRESETS"``).
      show: what the help prints of it and the choices list (default: the value).
    """

    def __init__(self, module: str, name: str, show=None):
        self.module, self.name, self.show = module, name, show

    def value(self):
        return getattr(importlib.import_module(self.module), self.name)

    def shown(self):
        return self.value() if self.show is None else self.show(self.value())

    def __str__(self) -> str:
        return str(self.shown())

    def __contains__(self, item) -> bool:
        return item in self.value()

    def __iter__(self):
        return iter(self.shown())
